"""Builders that turn a scenario's ``[policy]`` section into a policy object (TOML parsing lives here,
not in :mod:`hqp_tpm.policies`). Importing this package fills :data:`POLICY_BUILDERS`."""

from hqp_tpm.app.policy_builders import admittance, algorithm1, petric, switching, whole_body  # noqa: F401
from hqp_tpm.app.policy_builders.registry import POLICY_BUILDERS, register_policy

__all__ = ["POLICY_BUILDERS", "register_policy"]
