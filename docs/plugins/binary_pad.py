"""A sensor of your own: a binary pad, whose taxels say only "touched" or "not touched".

Many cheap tactile arrays (switch matrices, thresholded piezo-resistive foils) give one bit per
taxel. This simulator file registers ``binary``: the world's built-in fast glance (the paper's
line glance, or the extended glance of a world with y, phi_y or height fields), its pressure
image read out as ``ON_PA`` where a taxel feels more than ``THRESHOLD_PA`` and 0 elsewhere. Use:

    ham table build --simulator-file docs/plugins/binary_pad.py --grid 51 --out binary.h5

(``--simulator binary`` is implied: the file registers one simulator). The table, and every run
trained on it, keeps this file's text, so nothing else needs the file later.
"""

from dataclasses import replace

from ham.world.config import make_simulator
from ham.world.simulators import register_simulator

THRESHOLD_PA = 1000.0  # a taxel is "on" above 1 kPa
ON_PA = 5000.0  # what an "on" taxel reads: the fast model's taxels read 0 .. 5 kPa at 2 N


class BinaryPad:
    """The fast glance of the world, with one bit per taxel."""

    name = "binary"

    def __init__(self, objects, sensor, pose, glance, device="cpu", world=None):
        # the same world with the built-in fast simulator: its glance for these pose dims
        self.fast = make_simulator(
            replace(world, simulator="fast", simulator_file=None), device=device
        )
        self.objects = self.fast.objects

    def glance(self, object_ids, q_x, q_phi, **kwargs):
        r = self.fast.glance(object_ids, q_x, q_phi, **kwargs)
        on = (r.pressure > THRESHOLD_PA).to(r.pressure.dtype)
        return replace(r, pressure=on * ON_PA)

    def describe(self):
        return {**self.fast.describe(), "readout": f"binary: > {THRESHOLD_PA:g} Pa reads {ON_PA:g}"}


register_simulator("binary", BinaryPad)
