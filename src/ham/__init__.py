"""ham: the Haptic Attention Model (Fleer, Moringen, Klatzky, Ritter; PLOS ONE 2020).

Data flows one way: world (objects, sensor, glance) -> table -> agent -> loss -> evaluation -> report.
"""

__version__ = "0.1.0"
