"""Array-level solvers of prioritized stacks. They see only arrays, never robots or tasks."""

from hqp_tpm.solvers.damping import pinv
from hqp_tpm.solvers.levels import Level, as_levels
from hqp_tpm.solvers.nullspace import nullspace
from hqp_tpm.solvers.tpm import TPMFactors, tpm, tpm_factors, tpm_reference

__all__ = ["Level", "TPMFactors", "as_levels", "nullspace", "pinv", "tpm", "tpm_factors", "tpm_reference"]
