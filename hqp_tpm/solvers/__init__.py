"""Array-level solvers of prioritized stacks. They see only arrays, never robots or tasks.

May import: :mod:`hqp_tpm.errors`, numpy, scipy, and (on first use) qpsolvers.
"""

from hqp_tpm.solvers.cascaded_qp import CascadeInfo, cascaded_qp
from hqp_tpm.solvers.damping import pinv
from hqp_tpm.solvers.levels import Level, as_levels
from hqp_tpm.solvers.nullspace import nullspace
from hqp_tpm.solvers.pwdls import pwdls
from hqp_tpm.solvers.registry import solve
from hqp_tpm.solvers.sns import SNSInfo, sns, sns_tpm, sns_tpm_reference
from hqp_tpm.solvers.tpm import TPMFactors, tpm, tpm_factors, tpm_reference

__all__ = ["CascadeInfo", "Level", "SNSInfo", "TPMFactors", "as_levels", "cascaded_qp", "nullspace", "pinv", "pwdls",
           "sns", "sns_tpm", "sns_tpm_reference", "solve", "tpm", "tpm_factors", "tpm_reference"]
