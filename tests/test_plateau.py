"""The plateau stopping rule of the training loop (``armpose.train.Plateau``)."""
import numpy as np

from armpose.train import Plateau


def run(losses, delta=0.01, patience=200) -> int | None:
    """The step at which ``Plateau`` stops on ``losses`` (one per step from 1), or None."""
    plateau = Plateau(delta, patience)
    for step, loss in enumerate(losses, start=1):
        if plateau.update(step, loss):
            return step
    return None


def noisy(mean, seed=0, std=0.3):
    return np.asarray(mean) + np.random.default_rng(seed).normal(0, std, len(mean))


def test_a_low_first_batch_does_not_stop_a_falling_loss():
    # falls 3 % per 100 steps, under batch noise; the first batch is unusually easy
    mean = 2.0 * 0.97 ** (np.arange(1200) / 100)
    losses = noisy(mean)
    losses[0] = 0.8
    assert run(losses) is None


def test_a_flat_loss_stops_after_the_window_plus_patience():
    step = run(noisy(np.full(2000, 2.0), seed=1))
    assert step is not None and 250 <= step <= 450


def test_a_loss_that_falls_then_flattens_stops_after_it_flattens():
    mean = np.concatenate([np.linspace(3.0, 1.5, 600), np.full(1400, 1.5)])
    step = run(noisy(mean, seed=2, std=0.2))
    assert step is not None and 600 < step <= 1100


def test_state_round_trip_gives_the_same_stop():
    losses = noisy(np.concatenate([np.linspace(3.0, 1.5, 300), np.full(700, 1.5)]), seed=3)
    whole = run(losses)
    first = Plateau(0.01, 200)
    for step, loss in enumerate(losses[:250], start=1):
        assert not first.update(step, loss)
    second = Plateau(0.01, 200, state=dict(first.state))
    resumed = next(step for step, loss in enumerate(losses[250:], start=251) if second.update(step, loss))
    assert resumed == whole


def test_restore_keeps_a_current_state_and_drops_an_old_one():
    current = Plateau(0.01, 200)
    for step in range(1, 80):
        current.update(step, 2.0)
    resumed = Plateau(0.01, 200)
    resumed.restore(dict(current.state))
    assert resumed.state == current.state
    fresh = Plateau(0.01, 200)
    fresh.restore({"smooth": 1.0, "best": 1.0, "best_step": 3})   # written by the rule before the fix
    assert fresh.state["count"] == 0 and fresh.state["best"] is None
    fresh.restore(None)
    assert fresh.state["count"] == 0
