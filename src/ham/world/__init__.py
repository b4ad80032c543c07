"""The haptic world: objects, the Myrmex sensor, the glance (fast and MuJoCo), glance tables and
glance sources. Depends on nothing else in ``ham``."""
