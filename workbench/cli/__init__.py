"""The command line, its commands and the scenario pipeline."""
