"""Learning: the batched training environment, the hybrid REINFORCE loss, the train loop with
checkpoints and resume, evaluation. Depends on ``ham.world`` and ``ham.model``."""
