"""Learning: the batched training environment, the hybrid REINFORCE loss, the train loop with
checkpoints and resume, evaluation, and exact reference planners. Depends on ``world``,
``envs`` and ``model``."""
