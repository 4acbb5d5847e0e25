"""``--light`` specifications: ``distant:DX,DY,DZ[:INTENSITY[:R,G,B]]`` and
``point:X,Y,Z[:INTENSITY[:R,G,B]]``.

A distant light's vector points from the surface towards the light and its intensity is
the irradiance on a surface facing it (E_perp); a point light's intensity is its radiant
intensity (E = I cos(theta) / d^2). Both default to 1, white. Imports numpy only.
"""

from __future__ import annotations

import math

from ...shading import Light

#: The kinds ``--light`` accepts and what their three numbers are.
SPEC_KINDS = {"distant": "direction DX,DY,DZ", "point": "position X,Y,Z"}


def parse_light_spec(text: str, index: int) -> Light:
    """The :class:`Light` of one ``--light`` value, named ``--light INDEX``.

    Raises ``ValueError`` with a one-line reason naming the option and what is wrong.
    """
    name = f"--light {index}"
    fields = str(text).strip().split(":")
    kind = fields[0].strip().lower()
    if kind not in SPEC_KINDS:
        raise ValueError(
            f"{name} {text!r}: unknown light kind {fields[0]!r}; use "
            "distant:DX,DY,DZ[:INTENSITY[:R,G,B]] or point:X,Y,Z[:INTENSITY[:R,G,B]]"
        )
    if not 2 <= len(fields) <= 4:
        raise ValueError(f"{name} {text!r}: expected {kind}:{SPEC_KINDS[kind].split()[1]}[:INTENSITY[:R,G,B]]")
    vector = _numbers(fields[1], 3, SPEC_KINDS[kind], name, text)
    intensity = _numbers(fields[2], 1, "INTENSITY", name, text)[0] if len(fields) > 2 else 1.0
    rgb = _numbers(fields[3], 3, "colour R,G,B", name, text) if len(fields) > 3 else [1.0, 1.0, 1.0]
    if intensity < 0 or any(c < 0 for c in rgb):
        raise ValueError(f"{name} {text!r}: intensity and colour must be >= 0")
    value = [intensity * c for c in rgb]
    if kind == "distant":
        if not any(vector):
            raise ValueError(f"{name} {text!r}: the direction has zero length")
        return Light.make("distant", name, value, direction=vector)
    return Light.make("point", name, value, position=vector)


def _numbers(field: str, count: int, what: str, name: str, text: str) -> list[float]:
    parts = field.split(",")
    try:
        values = [float(p) for p in parts]
    except ValueError:
        values = []
    if len(values) != count or not all(math.isfinite(v) for v in values):
        raise ValueError(f"{name} {text!r}: {what} must be {count} finite number{'s' if count > 1 else ''}, got {field!r}")
    return values
