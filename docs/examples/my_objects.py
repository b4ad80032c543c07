"""My four objects (heights in metres, x in [-0.045, 0.045] across the 9 cm block)."""
import numpy as np

from ham.world.objects import HapticObject, register

register(HapticObject.from_function(
    "cylinder",  # a vectorized h(x): one height per x
    lambda x: 0.02 + 0.5 * np.sqrt(np.clip(0.045**2 - x**2, 0, None)),
    description="half cylinder (flattened) on a 2 cm plinth"))
register(HapticObject.from_polyline(
    "wedge", [(-0.045, 0.0), (0.045, 0.03)], description="low wedge rising to the right"))
register(HapticObject.from_heightmap(
    "bump", [0.01, 0.01, 0.04, 0.01, 0.01], description="central bump"))
register(HapticObject.from_polyline(
    "notch",  # two points with the same x make a vertical step
    [(-0.045, 0.04), (-0.005, 0.04), (-0.005, 0.02), (0.005, 0.02), (0.005, 0.04), (0.045, 0.04)],
    description="flat top with a 1 cm notch"))
