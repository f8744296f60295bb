"""θ's layout: the named blocks of the parameter vector, in order.

Every entry of θ belongs to one :class:`Block`, and one :class:`ParameterLayout` says where
each block sits. A model's layout (:meth:`ParameterLayout.for_model`, eq. 7's θ_Ψ, θ_Σ, θ_Γ)
is::

    θ = [dynamics ..., damping, force ..., process_var ..., obs_var ..., obs_rel_var ...]

* **dynamics**: the coefficients of U (``c[q1^2]``, …), the network weights of a neural
  potential, or the declared parameters of a user's model; the block is named after its prior
  group (``coefficients`` or ``parameters``);
* ``damping``: the damping rate γ of a damped model (entry ``gamma``);
* ``force``: the parameters θ_F of a driven model's generalised force
  (:mod:`symplid.dynamics._forcing`), named parameters of group ``parameters``;
* ``process_var``: Σ's variance(s), absent without process noise;
* ``obs_var``: Γ's additive variance(s), absent for purely multiplicative noise;
* ``obs_rel_var``: the relative variances r of multiplicative noise.

A block holds no entry when the model has none of it, and is then left out. A posterior
appends each learned initial state with :meth:`ParameterLayout.extend`: blocks ``x0[k]`` of
group ``initial_state`` with entries ``x0[k].q1``, …, ``x0[k].pd``.

The layout only names and places entries; bounds, priors and the map to the unconstrained
space belong to :class:`~symplid.model._params.ParameterSpace`, which is built from the
layout's ``names`` and ``groups``.
"""

from __future__ import annotations

from collections.abc import Iterable, Sequence
from dataclasses import dataclass
from typing import Any

import jax
import jax.numpy as jnp
import numpy as np

from symplid.dynamics._potentials import coefficient_name

__all__ = ["NOISE_BLOCKS", "Block", "ParameterLayout"]

Array = jax.Array

NOISE_BLOCKS = ("process_var", "obs_var", "obs_rel_var")
"""The blocks of noise variances, in their order in θ."""


@dataclass(frozen=True)
class Block:
    """A named run of θ's entries.

    Parameters
    ----------
    name
        The block's name (``coefficients``, ``damping``, ``process_var``, ``x0[0]``, …).
    group
        The prior group of its entries (:class:`~symplid.model._prior_spec.PriorSpec`).
    entries
        The names of its entries, in order.
    """

    name: str
    group: str
    entries: tuple[str, ...]

    def __post_init__(self) -> None:
        object.__setattr__(self, "entries", tuple(str(e) for e in self.entries))

    @property
    def size(self) -> int:
        """The number of entries."""
        return len(self.entries)


class ParameterLayout:
    """θ as a sequence of :class:`Block`; views of θ by block name.

    Parameters
    ----------
    blocks
        The blocks in order; names must be distinct. Empty blocks are dropped.
    """

    def __init__(self, blocks: Iterable[Block]) -> None:
        self.blocks: tuple[Block, ...] = tuple(b for b in blocks if b.size > 0)
        self._slices: dict[str, slice] = {}
        start = 0
        for block in self.blocks:
            if block.name in self._slices:
                raise ValueError(f"θ's layout has two blocks named {block.name!r}")
            self._slices[block.name] = slice(start, start + block.size)
            start += block.size
        self.size = start
        self.names: tuple[str, ...] = tuple(e for b in self.blocks for e in b.entries)
        self.groups: tuple[str, ...] = tuple(b.group for b in self.blocks for _ in b.entries)

    # ------------------------------------------------------------------ construction
    @classmethod
    def for_model(
        cls,
        param_names: Sequence[str],
        parameter_group: str = "coefficients",
        *,
        damping: bool = False,
        noise: str = "isotropic",
        state_dim: int,
        obs_noise_labels: Sequence[str] = ("",),
        additive: bool = True,
        multiplicative: bool = False,
        deterministic: bool = False,
        force_names: Sequence[str] = (),
    ) -> ParameterLayout:
        """The layout of a state-space model's θ (module docstring).

        Parameters
        ----------
        param_names
            The Hamiltonian's (or potential's) parameter names; monomials become ``c[...]``
            (:func:`~symplid.dynamics._potentials.coefficient_name`).
        parameter_group
            The prior group, and block name, of those parameters.
        damping
            Whether the model learns a damping rate γ.
        noise
            ``"isotropic"``, ``"diagonal"`` or ``"per-kind"``: one process variance, or one per
            state component (``state_dim`` of them) when diagonal.
        obs_noise_labels
            The label of each observation variance (``""`` for one variance, else the
            component's index or kind): entries ``obs_var[label]`` and ``obs_rel_var[label]``.
        additive, multiplicative
            Whether the observation noise has additive variances, relative ones, or both.
        deterministic
            A model without process noise has no ``process_var``.
        force_names
            The parameters of a generalised force (block ``force``, group ``parameters``).
        """
        num_process = 0 if deterministic else (int(state_dim) if noise == "diagonal" else 1)
        process = (
            [f"process_var[{i}]" for i in range(num_process)] if noise == "diagonal"
            else ["process_var"] * num_process
        )
        labels = [f"[{label}]" if label else "" for label in obs_noise_labels]
        return cls([
            Block(parameter_group, parameter_group,
                  tuple(coefficient_name(str(n)) for n in param_names)),
            Block("damping", "damping", ("gamma",) if damping else ()),
            Block("force", "parameters", tuple(str(n) for n in force_names)),
            Block("process_var", "process_var", tuple(process)),
            Block("obs_var", "obs_var", tuple(f"obs_var{s}" for s in labels) if additive else ()),
            Block("obs_rel_var", "obs_rel_var",
                  tuple(f"obs_rel_var{s}" for s in labels) if multiplicative else ()),
        ])

    @classmethod
    def from_groups(cls, names: Sequence[str], groups: Sequence[str]) -> ParameterLayout:
        """A layout read from entry names and groups: each run of one group is a block named
        after it (for a model that states only ``param_names`` and ``param_groups``)."""
        if len(names) != len(groups):
            raise ValueError(f"{len(names)} names but {len(groups)} groups")
        runs: list[tuple[str, list[str]]] = []
        for name, group in zip(names, groups, strict=True):
            if runs and runs[-1][0] == group:
                runs[-1][1].append(str(name))
            else:
                runs.append((str(group), [str(name)]))
        taken: dict[str, int] = {}
        blocks = []
        for group, entries in runs:
            k = taken.get(group, 0)
            taken[group] = k + 1
            blocks.append(Block(group if k == 0 else f"{group}#{k}", group, tuple(entries)))
        return cls(blocks)

    def extend(self, blocks: Iterable[Block]) -> ParameterLayout:
        """This layout with ``blocks`` appended (a posterior's initial states)."""
        return ParameterLayout([*self.blocks, *blocks])

    # ------------------------------------------------------------------ description
    @property
    def block_names(self) -> tuple[str, ...]:
        return tuple(b.name for b in self.blocks)

    def __contains__(self, name: object) -> bool:
        return name in self._slices

    def __len__(self) -> int:
        return self.size

    def __eq__(self, other: object) -> bool:
        return isinstance(other, ParameterLayout) and self.blocks == other.blocks

    __hash__ = None  # type: ignore[assignment]

    def __repr__(self) -> str:
        parts = ", ".join(f"{b.name}: {b.size}" for b in self.blocks)
        return f"ParameterLayout({parts})"

    def block(self, name: str) -> Block:
        """The block called ``name`` (``KeyError`` when the layout has none)."""
        return self.blocks[self._index(name)]

    def slice(self, block: str | Block) -> slice:
        """Where ``block`` (a name or a :class:`Block`) sits in θ."""
        name = block.name if isinstance(block, Block) else block
        self._index(name)
        return self._slices[name]

    def size_of(self, name: str) -> int:
        """The number of entries of block ``name``; 0 when the layout has no such block."""
        return self.block(name).size if name in self else 0

    def _index(self, name: str) -> int:
        if name not in self._slices:
            raise KeyError(f"θ has no block {name!r}; its blocks: {', '.join(self.block_names)}")
        return self.block_names.index(name)

    # ------------------------------------------------------------------ views
    def unpack(self, theta: Any) -> dict[str, Any]:
        """θ ↦ ``{block name: its entries}``, along θ's last axis.

        θ may be a NumPy array (the views are NumPy arrays), or a JAX array, traced or
        batched (the views are JAX arrays).
        """
        theta = theta if isinstance(theta, np.ndarray) else jnp.asarray(theta)
        if theta.ndim == 0 or theta.shape[-1] != self.size:
            raise ValueError(
                f"θ must have {self.size} entries on its last axis ({', '.join(self.names)}), "
                f"got shape {theta.shape}"
            )
        return {name: theta[..., sl] for name, sl in self._slices.items()}

    def pack(self, **blocks: Any) -> np.ndarray:
        """``block name = values`` ↦ θ (float64); a block left out is empty.

        ``damping`` (γ) is required when the layout has it and refused otherwise; a block
        the layout does not have may be given empty (e.g. ``process_var=()`` without process
        noise). Names that are not identifiers go through a mapping:
        ``layout.pack(**{"x0[0]": x0})``.
        """
        if ("damping" in self) != (blocks.get("damping") is not None):
            need = "needs a" if "damping" in self else "has no"
            raise ValueError(f"this model {need} damping rate: pass gamma accordingly")
        values = {k: np.ravel(np.asarray(v, dtype=float)) for k, v in blocks.items()
                  if v is not None}
        total = sum(v.size for v in values.values())
        if total != self.size:
            raise ValueError(f"θ has {self.size} entries ({self.names}), got {total}")
        for name, value in values.items():
            if value.size != self.size_of(name):
                raise ValueError(
                    f"θ's block {name!r} has {self.size_of(name)} entries, got {value.size}"
                )
        parts = [values[b.name] for b in self.blocks]
        return np.concatenate(parts).astype(float) if parts else np.zeros(0)
