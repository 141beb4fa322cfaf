"""Vehicle types with real dimensions (metres) and their mix in traffic."""
from __future__ import annotations

from dataclasses import dataclass


@dataclass(frozen=True)
class VehicleType:
    """A SUMO vType: id, vehicle class, size (m), and its share of generated traffic."""

    type_id: str
    vclass: str
    length_m: float
    width_m: float
    height_m: float
    share: float
    max_speed_mps: float
    gui_shape: str

    def to_dict(self) -> dict:
        return {"id": self.type_id, "vclass": self.vclass, "length_m": self.length_m, "width_m": self.width_m,
                "height_m": self.height_m, "share": self.share}


#: typical European sizes: a mid-size sedan, an SUV, a panel van, a rigid truck, a city bus
VEHICLE_TYPES: tuple[VehicleType, ...] = (
    VehicleType("car", "passenger", 4.60, 1.85, 1.48, 0.55, 50.0, "passenger/sedan"),
    VehicleType("suv", "passenger", 4.85, 1.95, 1.75, 0.20, 50.0, "passenger/van"),
    VehicleType("van", "delivery", 5.40, 2.05, 2.30, 0.12, 40.0, "delivery"),
    VehicleType("truck", "truck", 8.50, 2.50, 3.40, 0.08, 30.0, "truck"),
    VehicleType("bus", "bus", 12.00, 2.55, 3.10, 0.05, 25.0, "bus"),
)

#: the vTypeDistribution id that trips refer to
MIX_ID = "mix"


def vtypes_additional_xml(types: tuple[VehicleType, ...] = VEHICLE_TYPES) -> str:
    """The vTypes as a SUMO additional file, inside one ``vTypeDistribution`` named ``mix``."""
    rows = [
        f'        <vType id="{t.type_id}" vClass="{t.vclass}" length="{t.length_m}" width="{t.width_m}" '
        f'height="{t.height_m}" maxSpeed="{t.max_speed_mps}" guiShape="{t.gui_shape}" probability="{t.share}" '
        f'minGap="2.0" speedDev="0.1" lcStrategic="1.0"/>'
        for t in types
    ]
    return ('<?xml version="1.0" encoding="UTF-8"?>\n<additional>\n'
            f'    <vTypeDistribution id="{MIX_ID}">\n' + "\n".join(rows) + "\n    </vTypeDistribution>\n</additional>\n")
