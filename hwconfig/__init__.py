"""The hardware files and EDS files shipped with tcs, installed as the package ``tcs_hwconfig``.

Nothing to import: :mod:`tcs.resources` finds these files through :mod:`importlib.resources`.
"""
