"""An independent vehicle-bridge interaction simulator for realistic synthetic crossings.

Apart from the analysis model on purpose (its own beam elements, Rayleigh damping and
generalized-alpha time integration, none of `bayespinn.physics`): sprung axles on ISO 8608 road
roughness, an approach before the span, and a recording that starts before the entry.

- `road`: ISO 8608 profiles (sum of cosines, random phases)
- `beam`: the girder's own finite elements (segment EI, bearing springs, Rayleigh damping)
- `solver`: the coupled generalized-alpha integration
- `crossings`: crossings into a measurement file (`simulate`)
"""

from .crossings import VBISettings, simulate, simulate_crossing

__all__ = ["VBISettings", "simulate", "simulate_crossing"]
