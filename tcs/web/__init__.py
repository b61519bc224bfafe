"""The read-only web port of the service: a live status page, ``/status.json`` and Prometheus
``/metrics`` (``[web]`` in the hardware file; :mod:`tcs.web.server`). It imports the model and
the axes (reads only); nothing imports it but :mod:`tcs.app`."""
