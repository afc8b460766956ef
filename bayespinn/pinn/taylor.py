"""Taylor-mode (jet) derivatives of an MLP: u and its x- and t-derivatives in one forward pass.

A *jet* carries, for a batch of points, the value of a field and its derivatives along two input
directions: up to 4th order along x and up to 2nd order along t (the beam equation needs u_xxxx and u_tt,
the boundary and strain terms u_xx, the initial condition u_t; no mixed derivative is ever needed).

Propagation through the network (n-TangentProp style):

* a linear layer z = h W + b is linear, so every derivative component is multiplied by W (the bias
  only enters the value);
* tanh acts pointwise; with y = tanh(z) and y^(k) = d^k tanh / dz^k evaluated at z,
  y' = 1 - y^2, y'' = -2 y y', y''' = -2 (y'^2 + y y''), y'''' = -2 (3 y' y'' + y y'''),
  Faa di Bruno's formula for derivatives along one direction gives

      h1 = y' z1
      h2 = y' z2 + y'' z1^2
      h3 = y' z3 + 3 y'' z1 z2 + y''' z1^3
      h4 = y' z4 + y'' (4 z1 z3 + 3 z2^2) + 6 y''' z1^2 z2 + y'''' z1^4.

Everything is plain torch, so one ordinary ``backward()`` of a loss built from the jet gives the
parameter gradients (no ``create_graph`` and no nested autograd). Components that are identically zero
are carried as ``None`` and skipped (the first layer's input jet is mostly zeros).

Shapes: tensors are (M, N, d) -- M ensemble members (1 for a single network), N points, d features.
A component may also be (M, 1, d) when it is the same at every point (the first layer).

`autograd_jet` is the reference implementation with nested ``torch.autograd.grad`` (create_graph=True),
kept for tests and for the benchmark.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from typing import NamedTuple

import torch
from torch import Tensor

MAX_X_ORDER = 4
MAX_T_ORDER = 2


class Jet(NamedTuple):
    """A field and its derivatives along x and along t at a batch of points.

    Attributes
    ----------
    value : Tensor (M, N, d) or (M, N)
    x : tuple of Tensor or None, length kx <= 4; x[k-1] is the k-th derivative along x
    t : tuple of Tensor or None, length kt <= 2; t[k-1] is the k-th derivative along t
    """

    value: Tensor
    x: tuple[Tensor | None, ...] = ()
    t: tuple[Tensor | None, ...] = ()

    def map(self, fn: Callable[[Tensor], Tensor]) -> Jet:
        """fn applied to every present component (absent ones stay None), e.g. an index or a slice."""
        f = lambda c: None if c is None else fn(c)  # noqa: E731
        return Jet(fn(self.value), tuple(f(c) for c in self.x), tuple(f(c) for c in self.t))

    def squeeze(self, dim: int = -1) -> Jet:
        """The same jet with `dim` squeezed from every component (e.g. the output feature axis)."""
        return self.map(lambda c: c.squeeze(dim))

    def dx(self, k: int) -> Tensor:
        """k-th derivative along x (k = 0 is the value), zeros where the component is absent."""
        if k == 0:
            return self.value
        c = self.x[k - 1]
        return torch.zeros_like(self.value) if c is None else c.expand_as(self.value)

    def dt(self, k: int) -> Tensor:
        """k-th derivative along t (k = 0 is the value), zeros where the component is absent."""
        if k == 0:
            return self.value
        c = self.t[k - 1]
        return torch.zeros_like(self.value) if c is None else c.expand_as(self.value)


# ----------------------------------------------------------------------------- small None-aware helpers
def _add(*terms: Tensor | None) -> Tensor | None:
    out = None
    for a in terms:
        if a is not None:
            out = a if out is None else out + a
    return out


def _mul(*factors: Tensor | float | None) -> Tensor | None:
    out = None
    for f in factors:
        if f is None:
            return None
        out = f if out is None else out * f
    return out


# ----------------------------------------------------------------------------- layers
def linear_jet(jet: Jet, weight: Tensor, bias: Tensor) -> Jet:
    """z = h W + b applied to every component (bias on the value only).

    Parameters
    ----------
    jet : Jet with components (M, N, d_in) (or (M, 1, d_in))
    weight : Tensor (M, d_in, d_out)
    bias : Tensor (M, 1, d_out)
    """
    v = jet.value
    n = v.shape[1]
    comps = [v, *jet.x, *jet.t]
    full = [i for i, c in enumerate(comps) if c is not None and c.shape[1] == n]
    out: list[Tensor | None] = [None] * len(comps)
    # one batched matmul for every component that lives on all points
    # (torch.split, not slicing: its backward concatenates instead of zero-filling a buffer per slice)
    if len(full) > 1:
        parts = torch.split(torch.bmm(torch.cat([comps[i] for i in full], dim=1), weight), n, dim=1)
    else:
        parts = [torch.bmm(comps[i], weight) for i in full]
    for j, i in enumerate(full):
        out[i] = parts[j]
    for i, c in enumerate(comps):
        if c is not None and out[i] is None:  # broadcast components (M, 1, d_in)
            out[i] = torch.bmm(c, weight)
    out[0] = out[0] + bias
    kx = len(jet.x)
    return Jet(out[0], tuple(out[1 : 1 + kx]), tuple(out[1 + kx :]))


def tanh_jet(jet: Jet) -> Jet:
    """h = tanh(z) for a jet, by Faa di Bruno's formula along x (order <= 4) and t (order <= 2)."""
    z = jet.value
    kx, kt = len(jet.x), len(jet.t)
    y = torch.tanh(z)
    need = max(kx, kt)
    d1 = 1.0 - y * y if need >= 1 else None
    d2 = -2.0 * y * d1 if need >= 2 else None
    d3 = -2.0 * (d1 * d1 + y * d2) if need >= 3 else None
    d4 = -2.0 * (3.0 * d1 * d2 + y * d3) if need >= 4 else None
    return Jet(y, _faa_di_bruno(jet.x, d1, d2, d3, d4), _faa_di_bruno(jet.t, d1, d2, d3, d4))


def _faa_di_bruno(z: Sequence[Tensor | None], d1, d2, d3, d4) -> tuple[Tensor | None, ...]:
    """Derivatives of y(z(s)) along one direction, orders 1..len(z) (at most 4)."""
    k = len(z)
    z1, z2, z3, z4 = (list(z) + [None] * 4)[:4]
    out: list[Tensor | None] = []
    if k >= 1:
        out.append(_mul(d1, z1))
    if k >= 2:
        z1s = _mul(z1, z1)
        out.append(_add(_mul(d1, z2), _mul(d2, z1s)))
    if k >= 3:
        z1z2 = _mul(z1, z2)
        out.append(_add(_mul(d1, z3), _mul(3.0, d2, z1z2), _mul(d3, z1s, z1)))
    if k >= 4:
        inner = _add(_mul(4.0, z1, z3), _mul(3.0, z2, z2))
        out.append(_add(_mul(d1, z4), _mul(d2, inner), _mul(6.0, d3, z1s, z2), _mul(d4, z1s, z1s)))
    return tuple(out)


class _FusedTanhJet(torch.autograd.Function):
    """tanh of a stacked jet z (M, K, N, d) plus a bias on the value, with a hand-written backward.

    Components along axis 1: 0 the value, 1..kx the x-derivatives, kx+1..kx+kt the t-derivatives.
    The backward needs only the output jet y: with D(s) = tanh'(z(s)) = 1 - y(s)^2, whose derivatives
    D_n = -sum_k C(n, k) y_k y_{n-k} follow from y, the sensitivities are

        d y_n / d z_0 = D_n,    d y_n / d z_k = C(n, k) D_{n-k}   (k >= 1, same direction),

    because shifting z_k shifts z(s) by s^k / k!. This saves one tensor per layer instead of the dozens
    that autograd keeps for Faa di Bruno's formula, and needs about as many operations as the forward.
    """

    @staticmethod
    def forward(ctx, z: Tensor, bias: Tensor, kx: int, kt: int) -> Tensor:
        h = torch.empty_like(z)
        y = torch.tanh(z[:, 0] + bias, out=h[:, 0])
        d1 = 1.0 - y * y
        need = max(kx, kt)
        d2 = -2.0 * y * d1 if need >= 2 else None
        d3 = -2.0 * (d1 * d1 + y * d2) if need >= 3 else None
        d4 = -2.0 * (3.0 * d1 * d2 + y * d3) if need >= 4 else None
        for off, k in ((1, kx), (1 + kx, kt)):
            if k == 0:
                continue
            z1 = z[:, off]
            torch.mul(d1, z1, out=h[:, off])
            if k >= 2:
                z2 = z[:, off + 1]
                z1s = z1 * z1
                torch.addcmul(d1 * z2, d2, z1s, out=h[:, off + 1])
            if k >= 3:
                z3 = z[:, off + 2]
                z1z2 = z1 * z2
                torch.addcmul(
                    torch.addcmul(d1 * z3, d2, z1z2, value=3.0), d3, z1s * z1, out=h[:, off + 2]
                )
            if k >= 4:
                z4 = z[:, off + 3]
                inner = torch.addcmul(4.0 * z1 * z3, z2, z2, value=3.0)
                acc = torch.addcmul(d1 * z4, d2, inner)
                acc = torch.addcmul(acc, d3, z1s * z2, value=6.0)
                torch.addcmul(acc, d4, z1s * z1s, out=h[:, off + 3])
        ctx.kx, ctx.kt = kx, kt
        ctx.save_for_backward(h)
        return h

    @staticmethod
    @torch.autograd.function.once_differentiable
    def backward(ctx, g: Tensor):
        (h,) = ctx.saved_tensors
        kx, kt = ctx.kx, ctx.kt
        gz = torch.empty_like(h)
        y0 = h[:, 0]
        D0 = 1.0 - y0 * y0
        g0 = g[:, 0] * D0
        for off, k in ((1, kx), (1 + kx, kt)):
            if k == 0:
                continue
            y = [y0] + [h[:, off + i] for i in range(k)]
            gn = [None] + [g[:, off + i] for i in range(k)]
            # D_n for n = 1..k-... : jet of 1 - y^2 along this direction
            D = [D0]
            if k >= 1:
                D.append(-2.0 * y0 * y[1])
            if k >= 2:
                D.append(-2.0 * torch.addcmul(y0 * y[2], y[1], y[1]))
            if k >= 3:
                D.append(-2.0 * torch.addcmul(y0 * y[3], y[1], y[2], value=3.0))
            if k >= 4:
                acc = torch.addcmul(y0 * y[4], y[1], y[3], value=4.0)
                D.append(-2.0 * torch.addcmul(acc, y[2], y[2], value=3.0))
            for n in range(1, k + 1):
                g0 = torch.addcmul(g0, gn[n], D[n])
            for j in range(1, k + 1):  # gradient wrt z_j: sum_{n >= j} C(n, j) g_n D_{n-j}
                acc = gn[j] * D0
                for n in range(j + 1, k + 1):
                    acc = torch.addcmul(acc, gn[n], D[n - j], value=float(math.comb(n, j)))
                gz[:, off + j - 1].copy_(acc)
        gz[:, 0].copy_(g0)
        return gz, g0.sum(1, keepdim=True), None, None


def _stack(jet: Jet) -> Tensor:
    """(M, K, N, d) from a jet whose components are all present."""
    v = jet.value
    return torch.stack([c.expand_as(v) for c in (v, *jet.x, *jet.t)], dim=1)


def unstack(H: Tensor, kx: int, kt: int) -> Jet:
    """Jet (components (M, N, d)) from a stacked (M, K, N, d) tensor (views, no copy)."""
    c = H.unbind(1)
    return Jet(c[0], tuple(c[1 : 1 + kx]), tuple(c[1 + kx :]))


def hidden_stack(
    weights: Sequence[Tensor], biases: Sequence[Tensor], jet: Jet, *, fused: bool = True
) -> tuple[Tensor, int, int]:
    """The jet of the last hidden layer, stacked: (H (M, K, N, d), kx, kt).

    Parameters
    ----------
    weights, biases : the hidden layers only, Tensors (M, d_in, d_out) and (M, 1, d_out)
    jet : Jet of the network inputs, components (M, N, d_in) or (M, 1, d_in)
    fused : after the first layer, carry the jet as one stacked tensor through one matmul per layer and
        `_FusedTanhJet` (hand-written backward); False uses the component-wise formulas with autograd
        throughout (same numbers, slower, differentiable any number of times; kept for tests and for
        the nested-autograd reference)
    """
    h = tanh_jet(linear_jet(jet, weights[0], biases[0]))
    kx, kt = len(h.x), len(h.t)
    if not fused:
        for w, b in zip(weights[1:], biases[1:], strict=True):
            h = tanh_jet(linear_jet(h, w, b))
        return _stack(h), kx, kt
    H = _stack(h)
    M, K, N, _ = H.shape
    for w, b in zip(weights[1:], biases[1:], strict=True):
        Z = torch.bmm(H.reshape(M, K * N, -1), w).view(M, K, N, -1)
        H = _FusedTanhJet.apply(Z, b, kx, kt)
    return H, kx, kt


def linear_stack(H: Tensor, kx: int, kt: int, weight: Tensor, bias: Tensor) -> Jet:
    """The output layer on a stacked hidden jet: Jet of H W + b (bias on the value only)."""
    M, K, N, d = H.shape
    out = torch.bmm(H.reshape(M, K * N, d), weight).view(M, K, N, -1)
    j = unstack(out, kx, kt)
    return Jet(j.value + bias, j.x, j.t)


def mlp_jet(
    weights: Sequence[Tensor], biases: Sequence[Tensor], jet: Jet, *, fused: bool = True
) -> Jet:
    """Propagate an input jet through tanh hidden layers and a linear output layer.

    Parameters
    ----------
    weights : Tensors (M, d_in, d_out), one per layer (the last is the output layer); at least two
    biases : Tensors (M, 1, d_out)
    jet : Jet of the network inputs, components (M, N, d_in) or (M, 1, d_in)
    fused : see `hidden_stack`

    Returns
    -------
    Jet of the network outputs, components (M, N, d_out).
    """
    H, kx, kt = hidden_stack(weights[:-1], biases[:-1], jet, fused=fused)
    return linear_stack(H, kx, kt, weights[-1], biases[-1])


def cat_jets(*jets: Jet) -> Jet:
    """Jets of feature blocks (components (M, N, d_i), None for zero) joined along the feature axis."""
    first = jets[0].value

    def cat(parts) -> Tensor | None:
        if all(p is None for p in parts):
            return None
        full = [j.value if p is None else p for j, p in zip(jets, parts, strict=True)]
        shape = lambda j: (*first.shape[:-1], j.value.shape[-1])  # noqa: E731
        return torch.cat(
            [
                torch.zeros(shape(j), dtype=first.dtype, device=first.device)
                if p is None
                else f.to(first.dtype).expand(shape(j))
                for j, p, f in zip(jets, parts, full, strict=True)
            ],
            dim=-1,
        )

    kx, kt = len(jets[0].x), len(jets[0].t)
    return Jet(
        cat([j.value for j in jets]),
        tuple(cat([j.x[k] for j in jets]) for k in range(kx)),
        tuple(cat([j.t[k] for j in jets]) for k in range(kt)),
    )


def contract_jet(basis: Jet, c: Tensor) -> Jet:
    """Jet of w = sum_d phi_d c_d from a basis jet (components (M, N, D)) and coefficients c (M, D)."""
    f = lambda a: None if a is None else torch.bmm(a, c.unsqueeze(-1))[..., 0]  # noqa: E731
    return Jet(f(basis.value), tuple(f(a) for a in basis.x), tuple(f(a) for a in basis.t))


def product_jet(a: Jet, b: Jet) -> Jet:
    """Leibniz rule along each direction: the jet of a * b (orders of `a`)."""
    binom = ((1,), (1, 1), (1, 2, 1), (1, 3, 3, 1), (1, 4, 6, 4, 1))

    def comp(j: Jet, axis: str, k: int) -> Tensor | None:
        if k == 0:
            return j.value
        seq = j.x if axis == "x" else j.t
        return seq[k - 1] if k <= len(seq) else None

    def direction(axis: str, order: int) -> tuple[Tensor | None, ...]:
        return tuple(
            _add(
                *(
                    _mul(float(binom[n][k]), comp(a, axis, k), comp(b, axis, n - k))
                    for k in range(n + 1)
                )
            )
            for n in range(1, order + 1)
        )

    return Jet(a.value * b.value, direction("x", len(a.x)), direction("t", len(a.t)))


# ----------------------------------------------------------------------------- reference
def autograd_jet(
    fn: Callable[[Tensor, Tensor], Tensor], x: Tensor, t: Tensor, kx: int, kt: int
) -> Jet:
    """Reference derivatives by nested ``torch.autograd.grad`` (create_graph=True).

    Parameters
    ----------
    fn : maps x (M, N), t (M, N) to the field (M, N); every output point depends on its own input only
    x, t : Tensor (M, N), the coordinates along which derivatives are taken
    kx, kt : orders wanted along x (<= 4) and t (<= 2)

    Returns
    -------
    Jet with components (M, N), differentiable with respect to the parameters of `fn`.
    """
    x = x.detach().requires_grad_(True)
    t = t.detach().requires_grad_(True)
    u = fn(x, t)

    def chain(var: Tensor, order: int) -> tuple[Tensor, ...]:
        out, g = [], u
        for _ in range(order):
            g = torch.autograd.grad(g.sum(), var, create_graph=True)[0]
            out.append(g)
        return tuple(out)

    return Jet(u, chain(x, kx), chain(t, kt))
