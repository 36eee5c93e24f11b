"""Dynamic stack policies; importing this package registers them with the scenario builder."""

from hqp_tpm.policies import algorithm1  # noqa: F401
