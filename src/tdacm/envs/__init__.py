"""Gymnasium environments: ``gymnasium.make("tdacm/TipServo-v0")`` (see :mod:`.servo`)."""

from .._extras import require

gym = require("gymnasium", "env")

from .servo import TipServoEnv  # noqa: E402 (after the check for the extra)

ENV_ID = "tdacm/TipServo-v0"

if ENV_ID not in gym.registry:
    gym.register(id=ENV_ID, entry_point="tdacm.envs.servo:TipServoEnv", max_episode_steps=250)

__all__ = ["ENV_ID", "TipServoEnv"]
