"""The Haptic Attention Model's networks: tactile net, core, location net, classifier, baseline and
the whole agent. It sees glances only as tensors: it imports nothing but ``ham.errors``."""
