"""Real crossings in the modal reference: the speed, the entry time on the data's clock, the damping ratio
and the axles' dynamic forces inferred with the priors the user states, for one or several crossings of a
uniform pinned girder (`reference.crossings_reference`)."""

from .reference import (
    check_crossings,
    crossings_reference,
    needs_crossings,
    refuse_crossings,
)

__all__ = [
    "check_crossings",
    "crossings_reference",
    "needs_crossings",
    "refuse_crossings",
]
