"""The observers of design cards as FMU models (numpy only), one per runtime kernel
(:mod:`uiofmu.runtime.kernels`): each is built from a checked :class:`~uiofmu.runtime.card.Card` and wraps
the kernel's runtime in the card's ports."""

from __future__ import annotations

import numpy as np

from .delayed import DelayedRuntime
from .models import StatefulModel
from .observer import Runtime
from .schedules import StepRejected
from .window import WindowRuntime


class ObserverModel(StatefulModel):
    """The observer of a design card as FMU ports: ``y, u -> xhat, r, dhat`` (a functional observer's
    ``y, u -> zhat``)."""

    kind = "observer"

    def __init__(self, card):
        self.card = card
        self.rt = Runtime(card)
        arrays = {"xhat0": self.rt.xhat0.copy(), "h_prev0": np.array([self.rt.h_prev0]), "y": self.rt.y,
                  "u": self.rt.u, "mode_prev0": np.array([float(self.rt.mode_prev0)]),
                  "mode": np.array([float(self.rt.mode)])}
        self._declare(self.card.ports, arrays)
        self.dirty = True

    def initialize(self) -> None:
        """Take the parameters (called when leaving initialisation mode); raises StepRejected
        for an h_prev0 that is not a design interval or a mode_prev0 that is not a mode, and
        then nothing has changed."""
        named = self.named
        if "h_prev0" in named:                         # checked before anything changes
            h_prev0 = float(named["h_prev0"].values[0])
            self.rt.schedule.output_matrices(0, h_prev0)
            self.rt.h_prev0 = h_prev0
        if "mode_prev0" in named:
            mode_prev0 = int(named["mode_prev0"].values[0])
            try:
                self.rt.schedule.index(mode_prev0, "mode_prev0")
            except ValueError as exc:
                raise StepRejected(str(exc)) from None
            self.rt.mode_prev0 = mode_prev0
        self.rt.xhat0 = named["xhat0"].values.copy()
        self.rt.reset()
        self.dirty = True

    def notices(self) -> list:
        """Messages the schedule left for the log (drained)."""
        out = list(self.rt.schedule.notices)
        self.rt.schedule.notices.clear()
        return out

    def refresh(self) -> None:
        """Recompute the outputs from the current inputs and state."""
        named = self.named
        if self.rt.functional:
            named["zhat"].values[:] = self.rt.zhat()
        if self.rt.zhat_only:
            self.dirty = False
            return
        named["xhat"].values[:] = self.rt.xhat()
        named["r"].values[:] = self.rt.residual()
        if self.rt.has_dhat:
            named["dhat"].values[:] = self.rt.dhat()
        self.dirty = False

    def _ports_to_runtime(self) -> None:
        if "mode" in self.named:
            self.rt.set_mode(int(self.named["mode"].values[0]))

    def _runtime_to_ports(self) -> None:
        if "mode" in self.named:
            self.named["mode"].values[0] = self.rt.mode

    def step(self, t: float, h: float) -> None:
        """One communication step; raises StepRejected or RuntimeInputError."""
        self._ports_to_runtime()
        self.rt.step(h)
        self.dirty = True


class FunctionalModel(StatefulModel):
    """A window-kernel observer (:mod:`uiofmu.runtime.window`) as FMU ports: ``y, theta -> gx, gx_valid``."""

    kind = "observer"

    def __init__(self, card):
        self.card = card
        self.rt = WindowRuntime(card)
        self._declare(self.card.ports, {"y": self.rt.y, "theta": self.rt.theta})
        self.dirty = True

    def initialize(self) -> None:
        """No parameters: back to an empty window."""
        self.rt.reset()
        self.dirty = True

    def notices(self) -> list:
        """Messages for the log (none)."""
        return []

    def refresh(self) -> None:
        """Recompute ``gx`` and ``gx_valid`` from the window and the current inputs."""
        self.named["gx"].values[:] = self.rt.gx()
        self.named["gx_valid"].values[0] = 1.0 if self.rt.valid else 0.0
        self.dirty = False

    def step(self, t: float, h: float) -> None:
        """One communication step; raises StepRejected or RuntimeInputError."""
        self.rt.step(h)
        self.dirty = True


class DelayedModel(StatefulModel):
    """A delayed-kernel observer (:mod:`uiofmu.runtime.delayed`) as FMU ports:
    ``y, ydot, u -> xhat, thetahat, r, sigma_min, valid``."""

    kind = "observer"

    def __init__(self, card):
        self.card = card
        self.rt = DelayedRuntime(card)
        self._declare(self.card.ports, {"xhat0": self.rt.xhat0.copy(), "y": self.rt.y, "ydot": self.rt.ydot,
                                        "u": self.rt.u})
        self.dirty = True

    def initialize(self) -> None:
        """Take ``xhat0`` and start over (empty delay buffer)."""
        self.rt.xhat0 = self.named["xhat0"].values.copy()
        self.rt.reset()
        self.dirty = True

    def notices(self) -> list:
        """The kernel's notes for the log (validity lost; drained)."""
        out = list(self.rt.notices)
        self.rt.notices.clear()
        return out

    def refresh(self) -> None:
        """Recompute the outputs from the current inputs and state."""
        named = self.named
        named["xhat"].values[:] = self.rt.xhat()
        named["thetahat"].values[:] = self.rt.theta()
        named["r"].values[:] = self.rt.residual()
        named["sigma_min"].values[0] = self.rt.margin()
        named["valid"].values[0] = 1.0 if self.rt.valid else 0.0
        self.dirty = False

    def step(self, t: float, h: float) -> None:
        """One communication step; raises StepRejected or RuntimeInputError."""
        self.rt.step(h)
        self.dirty = True


__all__ = ["DelayedModel", "FunctionalModel", "ObserverModel"]
