"""The one selector of an integrator by its CLI/YAML name (``rosenbrock``, ``dopri54``,
``rk4``, ``scipy-<method>``). The explicit integrators and their shared pieces live in
rig.model.integrators, the stiff one (Rosenbrock) in rig.model.integrators_stiff."""

from __future__ import annotations

from rig.errors import InputError
from rig.model.integrators import DormandPrince, Integrator, RungeKutta4, ScipyIntegrator
from rig.model.integrators_stiff import Rosenbrock


def by_name(name: str, rtol: float = 1e-6, max_step: float = 2e-4) -> Integrator:
    """Integrator from a CLI/YAML name: rosenbrock, dopri54, rk4, or scipy-<method>."""
    if name == "dopri54":
        return DormandPrince(rtol=rtol, max_step=max_step)
    if name == "rk4":
        return RungeKutta4()
    if name == "rosenbrock":
        return Rosenbrock(rtol=rtol, max_step=max_step)
    if name.startswith("scipy-"):
        return ScipyIntegrator(method=name.split("-", 1)[1], rtol=rtol, max_step=max_step)
    raise InputError(f"integrator: expected rosenbrock, dopri54, rk4 or scipy-<method>, got "
                     f"{name!r}")
