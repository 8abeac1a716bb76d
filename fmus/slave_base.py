"""A pythonfmu slave base class whose modelDescription validates clean.

A bare pythonfmu slave has no units, leaves outputs without `initial` and
omits `ModelStructure/InitialUnknowns`, so `fmpy.validation` rejects it.
Subclasses declare their variables once as `Var` records (name, causality,
unit, description, start) and get a complete, valid description.
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import Any, ClassVar
from xml.etree.ElementTree import Element, SubElement

from pythonfmu import Boolean, Fmi2Causality, Fmi2Initial, Fmi2Slave, Fmi2Variability, Integer, Real, String
from pythonfmu.default_experiment import DefaultExperiment

from fmus.units import base_unit_attributes

_TYPES = {"Real": Real, "Integer": Integer, "Boolean": Boolean, "String": String}
_CASTS = {"Real": float, "Integer": int, "Boolean": bool, "String": str}


@dataclass(frozen=True)
class Var:
    """One FMU variable as the modelDescription should describe it."""

    name: str
    causality: str  # "input" | "output" | "parameter"
    description: str
    unit: str = "1"
    start: Any = 0.0  # required for inputs and parameters; outputs are calculated
    type: str = "Real"  # "Real" | "Integer" | "Boolean" | "String"
    variability: str | None = None  # default: "fixed" for parameters, else continuous/discrete

    def resolved_variability(self) -> str:
        if self.variability:
            return self.variability
        if self.causality == "parameter":
            return "fixed"
        return "continuous" if self.type == "Real" else "discrete"


class V2iSlave(Fmi2Slave):
    """Base of the project's FMUs: variables live in `self.values` by name.

    Subclasses set `VARIABLES`, `DESCRIPTION` and `DEFAULT_STEP` and implement
    `initialize()` (after parameters are set) and `step(t, dt)`.
    """

    VARIABLES: ClassVar[tuple[Var, ...]] = ()
    DESCRIPTION: ClassVar[str] = ""
    DEFAULT_STEP: ClassVar[float] = 0.01
    author = "v2i-cosim"
    license = "Apache-2.0"

    def __init__(self, **kwargs):
        super().__init__(**kwargs)
        self.description = self.DESCRIPTION
        self.default_experiment = DefaultExperiment(start_time=0.0, step_size=self.DEFAULT_STEP)
        self.values: dict[str, Any] = {}
        for var in self.VARIABLES:
            self.values[var.name] = _CASTS[var.type](var.start)
            self.register_variable(self._scalar(var))

    def _scalar(self, var: Var):
        values, name, cast = self.values, var.name, _CASTS[var.type]
        kwargs = dict(
            causality=Fmi2Causality[var.causality],
            description=var.description,
            variability=Fmi2Variability[var.resolved_variability()],
            getter=lambda: values[name],
            setter=lambda value: values.__setitem__(name, cast(value)),
        )
        if var.causality == "output":
            kwargs["initial"] = Fmi2Initial.calculated
        return _TYPES[var.type](name, **kwargs)

    # -- FMI life cycle --------------------------------------------------------
    def exit_initialization_mode(self):
        self.initialize()

    def do_step(self, current_time: float, step_size: float) -> bool:
        self.step(current_time, step_size)
        return True

    def initialize(self) -> None:  # pragma: no cover - subclasses override
        raise NotImplementedError

    def step(self, t: float, dt: float) -> None:  # pragma: no cover - subclasses override
        raise NotImplementedError

    # -- model description -----------------------------------------------------
    def to_xml(self, model_options: dict[str, str] = dict()) -> Element:
        root = super().to_xml(model_options)
        by_name = {var.name: var for var in self.VARIABLES}

        units = sorted({var.unit for var in self.VARIABLES if var.type == "Real"})
        unit_defs = Element("UnitDefinitions")
        for unit in units:
            SubElement(SubElement(unit_defs, "Unit", name=unit), "BaseUnit", base_unit_attributes(unit))
        # schema order: CoSimulation, UnitDefinitions, TypeDefinitions, LogCategories, ...
        root.insert(list(root).index(root.find("CoSimulation")) + 1, unit_defs)

        outputs: list[int] = []
        for index, scalar in enumerate(root.find("ModelVariables"), start=1):
            var = by_name[scalar.get("name")]
            if var.type == "Real":
                scalar.find("Real").set("unit", var.unit)
            if var.causality == "output":
                outputs.append(index)

        root.remove(root.find("ModelStructure"))
        structure = SubElement(root, "ModelStructure")
        if outputs:
            out_node = SubElement(structure, "Outputs")
            init_node = SubElement(structure, "InitialUnknowns")
            for index in outputs:
                SubElement(out_node, "Unknown", index=str(index))
                SubElement(init_node, "Unknown", index=str(index))
        return root
