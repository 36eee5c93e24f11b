"""Dynamic stack policies (papers/000 Algorithm 1, papers/003 switching and admittance, papers/004 schemes,
Romeo whole-body avoidance). Each follows :class:`hqp_tpm.control.policy.Policy`; scenario files build
them through :mod:`hqp_tpm.app.policy_builders`."""
