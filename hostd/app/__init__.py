"""The application: the command line and its commands, the configuration, the daemon."""
