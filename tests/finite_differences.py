"""Central finite differences of a scalar cost with respect to a closure's parameter vector."""

import torch


def central_difference(J, theta: torch.Tensor, rel_step: float = 1e-4) -> torch.Tensor:
    """``dJ/dtheta`` by central differences, steps ``rel_step * theta_i``; ``theta`` is restored.

    ``J()`` evaluates the cost (no autograd needed) at the current value of ``theta`` (a leaf
    tensor modified in place), shape ``(n,)``.
    """
    fd = torch.zeros(theta.numel(), dtype=torch.float64)
    with torch.no_grad():
        theta0 = theta.detach().clone()
        for i in range(theta.numel()):
            h = rel_step * float(theta0[i])
            for sign in (1, -1):
                theta.copy_(theta0)
                theta[i] += sign * h
                fd[i] += sign * float(J()) / (2 * h)
        theta.copy_(theta0)
    return fd
