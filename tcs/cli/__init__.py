"""Console scripts: ``tcs-server``, ``tcs-passwd``."""
