"""Gymnasium environments: ``gymnasium.make("tdacm/TipServo-v0")`` (see :mod:`.servo`) and its
vector form on the batched engine, ``gymnasium.make_vec("tdacm/TipServo-v0", num_envs=N,
vectorization_mode="vector_entry_point")`` (see :mod:`.vector`)."""

from .._extras import require

gym = require("gymnasium", "env")

from .servo import TipServoEnv  # noqa: E402 (after the check for the extra)
from .vector import TipServoVectorEnv  # noqa: E402

ENV_ID = "tdacm/TipServo-v0"

if ENV_ID not in gym.registry:
    gym.register(
        id=ENV_ID,
        entry_point="tdacm.envs.servo:TipServoEnv",
        vector_entry_point="tdacm.envs.vector:TipServoVectorEnv",
        max_episode_steps=250,
    )

__all__ = ["ENV_ID", "TipServoEnv", "TipServoVectorEnv"]
