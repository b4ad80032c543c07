"""A learner of your own: the paper's hybrid loss without its baseline (plain REINFORCE).

The paper's REINFORCE term weighs each pose's log-probability by the advantage ``r - b``, where
the baseline ``b`` is learned (Eq baseline). This learner weighs it by the reward ``r`` alone,
the ablation that shows what the baseline is for. It reads ``beta`` and the reductions, as the
hybrid learner does:

    ham train --plugin docs/plugins/no_baseline.py --learner no_baseline --table T.h5 ...

The run keeps this file's text (``config.json``), so ``ham evaluate`` and ``--resume`` need it
no more.
"""

from torch.nn import functional as F

from ham.learn.hybrid_loss import HybridLoss, reinforce_term, reward
from ham.learn.learners import register_learner


@register_learner("no_baseline", reads=("beta", "classification_reduction", "reinforce_reduction"))
def no_baseline(episode, config):
    last = episode.logits[-1]
    classification = F.cross_entropy(
        last, episode.objects, reduction=config.classification_reduction
    )
    r = reward(last.detach(), episode.objects)
    zero = last.new_zeros(())
    reinforce = zero
    if episode.policy is not None and episode.policy.trainable:
        advantage = r[None].expand(episode.values().shape)  # r for every pose, no baseline
        reinforce = reinforce_term(episode.locations[episode.chosen], episode.policy, advantage)
        if config.reinforce_reduction == "sum":
            reinforce = reinforce * episode.objects.shape[0]
    total = classification + config.beta * reinforce
    return HybridLoss(total, classification, reinforce, zero, r)
