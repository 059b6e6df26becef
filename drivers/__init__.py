"""The printer link: Marlin protocol framing, serial transport, streamer and simulated printer."""
