"""One way to declare, validate and change node parameters, shared by every node of the package.

A node lists its parameters as :class:`ParamSpec` rows and calls :func:`declare_parameters` once in its
constructor.  Each row carries its descriptor (description, range or choices, read-only flag), its own
validation and *when* a change takes effect:

* ``"live"``: accepted at any time, the node applies it from its next step (detector thresholds);
* ``"configure"``: accepted only while a lifecycle node is not active; it is applied by the next
  ``configure`` (``checkpoint``, ``domain``).  While active, a change is refused with that reason;
* ``"startup"``: read-only after start-up (a ROS read-only descriptor).

Start-up values that break a rule raise :class:`ParameterError`, whose one-line message names the
parameter and the allowed values; :func:`ompn_ros.ros.run.run_node` prints it and exits 2.
Changes at run time go through :meth:`ParamTable.check_changes`, for a node's
``add_on_set_parameters_callback``.
"""

from __future__ import annotations

import sys
from collections.abc import Callable, Iterable, Sequence
from dataclasses import dataclass
from typing import Any, Literal

from rcl_interfaces.msg import FloatingPointRange, IntegerRange, ParameterDescriptor, SetParametersResult
from rclpy.exceptions import ParameterException
from rclpy.node import Node
from rclpy.parameter import Parameter

from ompn_ros.errors import OMPNError

Apply = Literal["live", "configure", "startup"]


class ParameterError(OMPNError, ValueError):
    """A parameter value is invalid; the message names the parameter and what is allowed."""

    def __init__(self, name: str, reason: str) -> None:
        self.parameter = name
        super().__init__(f"invalid parameter '{name}': {reason}")


@dataclass(frozen=True)
class ParamSpec:
    """A node parameter: default, description, rules and when a change applies.

    ``choices`` restricts a string parameter, or every item of a string-array parameter.  ``check`` is an
    extra rule that returns a reason (or ``None``) for values the range and choices cannot express.
    ``dynamic``: the value may be of another type than the default (ROS dynamic typing; e.g. ``auto`` or
    a number), ``check`` then says which values are allowed.
    """

    name: str
    default: Any
    description: str
    int_range: tuple[int, int] | None = None
    float_range: tuple[float, float] | None = None
    choices: tuple[str, ...] | None = None
    apply: Apply = "startup"
    check: Callable[[Any], str | None] | None = None
    dynamic: bool = False

    def descriptor(self) -> ParameterDescriptor:
        """The ROS descriptor: ranges as ROS ranges, choices as a constraint text."""
        desc = ParameterDescriptor(description=self.description, read_only=self.apply == "startup",
                                   dynamic_typing=self.dynamic)
        if self.int_range is not None:
            lo, hi = self.int_range
            desc.integer_range = [IntegerRange(from_value=lo, to_value=hi, step=1)]
        if self.float_range is not None:
            flo, fhi = self.float_range
            desc.floating_point_range = [FloatingPointRange(from_value=flo, to_value=fhi, step=0.0)]
        if self.choices is not None:
            desc.additional_constraints = "one of: " + ", ".join(self.choices)
        return desc

    def validate(self, value: Any) -> None:
        """Raise :class:`ParameterError` if ``value`` breaks a rule of this parameter."""
        if self.choices is not None:
            items = value if isinstance(value, (list, tuple)) else [value]
            bad = [v for v in items if v not in self.choices]
            if bad:
                raise ParameterError(self.name, f"{value!r} is not one of {list(self.choices)}")
        for bounds in (self.int_range, self.float_range):
            if bounds is not None and not bounds[0] <= value <= bounds[1]:
                raise ParameterError(self.name, f"{value} is outside [{bounds[0]}, {bounds[1]}]")
        if self.check is not None:
            reason = self.check(value)
            if reason:
                raise ParameterError(self.name, reason)


class ParamTable:
    """The parameters of one node, declared once; validates start-up values and run-time changes."""

    def __init__(self, specs: Iterable[ParamSpec]) -> None:
        self.specs: dict[str, ParamSpec] = {}
        for spec in specs:
            if spec.name in self.specs:
                raise ValueError(f"parameter '{spec.name}' is listed twice")
            self.specs[spec.name] = spec

    def declare(self, node: Node) -> dict[str, Any]:
        """Declare every parameter on ``node`` and validate its start-up value."""
        values: dict[str, Any] = {}
        for spec in self.specs.values():
            try:
                value = node.declare_parameter(spec.name, spec.default, spec.descriptor()).value
            except ParameterException as exc:
                raise ParameterError(spec.name, str(exc)) from None
            spec.validate(value)
            values[spec.name] = value
        return values

    def check_changes(self, params: Sequence[Any], *, active: bool = False) -> SetParametersResult:
        """Accept or refuse a set of changes (for ``add_on_set_parameters_callback``).

        Unknown names (``use_sim_time`` and other rclpy parameters) are left to rclpy.  A change to a
        ``"configure"`` parameter is refused while ``active``, with the way to apply it.
        """
        for param in params:
            spec = self.specs.get(param.name)
            if spec is None:
                continue
            if spec.apply == "configure" and active:
                return SetParametersResult(
                    successful=False,
                    reason=f"'{spec.name}' cannot change while the node is active: deactivate, "
                    "clean up, set it, then configure",
                )
            try:
                spec.validate(param.value)
            except ParameterError as exc:
                return SetParametersResult(successful=False, reason=str(exc))
        return SetParametersResult(successful=True)


def declare_parameters(node: Node, specs: Sequence[ParamSpec]) -> dict[str, Any]:
    """Declare and validate ``specs`` on ``node`` (shorthand for ``ParamTable(specs).declare(node)``)."""
    return ParamTable(specs).declare(node)


def shown_default(default: Any) -> str:
    """A default as ``--help`` and docs/parameters.md show it: a parameter declared by its type only (a
    ``Parameter.Type``, e.g. an array that starts unset) as ``unset (string array)``, a string quoted,
    anything else as written."""
    if isinstance(default, Parameter.Type):
        kind = default.name.lower().replace("_", " ")
        return f"unset ({kind})"
    return repr(default)


def markdown_table(specs: Iterable[ParamSpec]) -> str:
    """The parameters as a Markdown table (name, default, allowed values, when a change applies,
    meaning): ``docs/parameters.md`` is generated from the nodes' own tables with this."""
    rows = ["| name | default | allowed | applies | meaning |", "|---|---|---|---|---|"]
    for spec in specs:
        bounds = spec.int_range or spec.float_range
        allowed = (f"{bounds[0]:g} to {bounds[1]:g}" if bounds is not None
                   else ", ".join(f"`{c}`" if c else "`''`" for c in spec.choices) if spec.choices else "")
        default = shown_default(spec.default)
        text = spec.description.replace("|", "\\|")
        rows.append(f"| `{spec.name}` | `{default}` | {allowed} | {spec.apply} | {text} |")
    return "\n".join(rows)


def help_text(prog: str, description: str, specs: Iterable[ParamSpec], usage: str = "") -> str:
    """``--help`` of a node: usage (``usage``: the node's own arguments), what it does, and every parameter
    with its default and rules."""
    own = f" {usage}" if usage else ""
    lines = [f"usage: {prog}{own} [--ros-args -p NAME:=VALUE ... | --params-file FILE | -r FROM:=TO ...]", "",
             description, "", "parameters (when a change applies: live | configure | startup):"]
    for spec in specs:
        bounds = spec.int_range or spec.float_range
        rule = (f", {bounds[0]:g} to {bounds[1]:g}" if bounds is not None
                else f", one of {list(spec.choices)}" if spec.choices else "")
        lines.append(f"  {spec.name} (default {shown_default(spec.default)}{rule}; {spec.apply}): "
                     f"{spec.description}")
    return "\n".join(lines)


def wants_help(args: Sequence[str] | None) -> bool:
    """True when the non-ROS part of the command line (``sys.argv`` when ``args`` is None) asks for
    ``-h``/``--help``; the caller then prints :func:`help_text` and exits before touching ROS."""
    argv = list(sys.argv if args is None else args)
    cut = argv.index("--ros-args") if "--ros-args" in argv else len(argv)
    return any(a in ("-h", "--help") for a in argv[1:cut])
