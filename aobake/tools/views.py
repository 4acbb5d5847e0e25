"""The named camera views of previews: ``{view: (azimuth, elevation)}`` in degrees.

Imports nothing (the CLI shows them in ``--help``).
"""

VIEWS = {"front": (-90.0, 10.0), "side": (0.0, 10.0), "top": (-90.0, 89.0), "iso": (-55.0, 30.0)}
