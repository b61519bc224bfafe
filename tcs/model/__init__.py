"""The telescope model shared by every module: events, persistent state, LOCAL, CONFIG, health."""
