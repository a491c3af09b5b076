"""SB3 callbacks of the training runs, also usable from rl-zoo3 (``callback:`` in the hyperparameter YAML).

- :class:`RewardTermsCallback`: the mean of every reward term the env reports in ``info`` (the
  ``reward_*`` keys, Gymnasium's convention, e.g. ``reward_tracking``, ``reward_ctrl``) over each
  rollout, as TensorBoard scalars ``reward_terms/<term>``.
"""

from __future__ import annotations

from collections import defaultdict

from stable_baselines3.common.callbacks import BaseCallback

PREFIX = "reward_"
"""Keys of ``info`` that are reward terms."""

TAG = "reward_terms"
"""TensorBoard section of the scalars."""


class RewardTermsCallback(BaseCallback):
    """Logs the rollout mean of each ``info["reward_<term>"]`` (per env step, raw env units) as
    ``reward_terms/<term>``; the terms of one step sum to the env's reward (before any normalization)."""

    def __init__(self, verbose: int = 0):
        super().__init__(verbose)
        self._sums: dict[str, float] = defaultdict(float)
        self._counts: dict[str, int] = defaultdict(int)

    def _on_step(self) -> bool:
        for info in self.locals.get("infos", ()):
            for key, value in info.items():
                if key.startswith(PREFIX):
                    try:
                        self._sums[key] += float(value)
                    except (TypeError, ValueError):
                        continue
                    self._counts[key] += 1
        return True

    def _on_rollout_end(self) -> None:
        for key, total in self._sums.items():
            self.logger.record(f"{TAG}/{key[len(PREFIX):]}", total / max(self._counts[key], 1))
        self._sums.clear()
        self._counts.clear()
