"""Sessions on either engine (issue 34), chosen by the task overrides alone."""

import numpy as np
from unigait.client import SessionConfig, open_session

ARTICULATED = '[physics]\nengine = "articulated"\n'
RAPIER = '[physics]\nengine = "rapier"\n'
CALM = (
    "[init]\nhip = [0.0, 0.0]\nthigh = [0.0, 0.0]\ncalf = [0.0, 0.0]\npitch = [0.0, 0.0]\n"
    "linvel = [0.0, 0.0]\nangvel = [0.0, 0.0]\n[randomization]\nenabled = false\n"
    "[noise]\nenabled = false\n[env]\nrandom_initial_episode_step = false\n"
)


def _stand(server: str, overrides: str, steps: int = 100) -> tuple[np.ndarray, np.ndarray]:
    """Observed joint angles and terminations over ``steps`` zero-action policy steps."""
    cfg = SessionConfig(num_envs=4, seed=3, task_overrides_toml=overrides)
    with open_session(server, cfg) as s:
        q = s.spec.obs.slice("q")
        zeros = np.zeros((4, 12), np.float32)
        angles, ended = [], []
        for _ in range(steps):
            r = s.step(zeros)
            assert np.isfinite(r.obs).all() and np.isfinite(r.reward).all()
            angles.append(r.obs[:, q])
            ended.append(r.terminated)
    return np.stack(angles), np.stack(ended)


def test_a_session_runs_on_the_articulated_engine(server):
    """Standing 2 s at action 0: no fall on either engine, the articulated run repeats bit for
    bit and is the default's, and it is not the rapier run (the override reached the physics)."""
    a, a_ended = _stand(server, CALM + ARTICULATED)
    again, _ = _stand(server, CALM + ARTICULATED)
    default, _ = _stand(server, CALM)
    r, r_ended = _stand(server, CALM + RAPIER)
    assert not a_ended.any() and not r_ended.any()
    np.testing.assert_array_equal(a, again)
    np.testing.assert_array_equal(a, default)
    assert not np.array_equal(a, r)
    # Both hold the default pose with the PD's sag (observed q: angle minus default, scale 1):
    # the engines' stances agree within 0.05 rad (measured 0.006).
    assert np.abs(a[-1] - r[-1]).max() < 0.05
