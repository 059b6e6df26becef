"""Code the test layers share (imported as ``support.X``); no test module imports another."""
