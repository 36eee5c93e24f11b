"""Dynamic stack policies; importing this package registers them with the scenario builder."""

import hqp_tpm.policies.whole_body  # noqa: F401
from hqp_tpm.policies import admittance, algorithm1, petric, switching  # noqa: F401
