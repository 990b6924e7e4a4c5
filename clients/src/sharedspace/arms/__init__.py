"""The reference arms: the learned rows of the bench's leaderboards, trained, shipped and chosen.

- :mod:`sharedspace.arms.rows` trains each network's seeds of an arm (the residual learner, the
  from-scratch recipe), ships their last checkpoints and scores them with the bench;
- :mod:`sharedspace.arms.best` chooses each task's best learned row on its validation split.

They use the trainer and the bench; the bench (:mod:`sharedspace.bench`) only scores.
"""
