"""Training schedules as pure functions of the training progress (0 at the first step, 1 at the last)."""

from __future__ import annotations


def difficulty_at(progress: float, max_difficulty: int, ramp_fraction: float = 0.5, min_difficulty: int = 0) -> int:
    """Curriculum over data difficulty: easy pairs first.

    Rises linearly from ``min_difficulty`` at progress 0 to ``max_difficulty`` at ``progress = ramp_fraction``
    and stays there (``ramp_fraction <= 0``: always ``max_difficulty``). Returns an int level.
    """
    if max_difficulty <= min_difficulty or ramp_fraction <= 0:
        return int(max_difficulty)
    t = min(max(progress / ramp_fraction, 0.0), 1.0)
    # each level gets an equal share of the ramp; the last level is reached exactly at the ramp's end
    levels = max_difficulty - min_difficulty + 1
    return int(min(min_difficulty + int(t * levels), max_difficulty))


def training_progress(global_step: int, max_steps: int, fallback_steps: int) -> float:
    """``global_step / max_steps`` in [0, 1]; ``fallback_steps`` when the trainer has no step budget (-1)."""
    total = max_steps if max_steps and max_steps > 0 else fallback_steps
    return min(max(global_step / max(total, 1), 0.0), 1.0)
