"""The Haptic Attention Model's networks: tactile net, core, location net, classifier, baseline and
the whole agent. Depends on nothing else in ``ham`` (it sees glances only as tensors)."""
