"""Build the testbed's MJCF from a parameter set: one model per fixture (``locked`` or ``free``).

The reference XML files beside this module are the default parameters' models (``python -m
sim.reference_models`` rewrites them, a test checks they are current); the simulator always builds from
parameters.
"""

from __future__ import annotations

import math
from pathlib import Path
from typing import TYPE_CHECKING

import mujoco

from models.errors import ParameterError
from models.gim8108_testbed.derived import (
    FIXTURES,
    SOLVER_TIME_CONSTANTS,
    derive,
    implicit_joint_damping,
    physics_timestep,
    solver_time_constants,
)

if TYPE_CHECKING:
    from sim.params import TestbedParams

HERE = Path(__file__).resolve().parent
MOTOR_HOUSING_HALF_HEIGHT_M = 0.02  # visual only: a 40 mm tall GIM8108 housing
LOADCELL_HALF_SIZE_M = 0.01  # visual only


def _f(x: float) -> str:
    return f"{x:.9g}"


def _axisymmetric(axial: float) -> str:
    """``diaginertia`` of a body spinning about z, thin-disc-like: the transverse values half the axial one as
    written (``_f``), in full precision, so that MuJoCo's A + B >= C holds whatever the rounding of C."""
    c = _f(axial)
    half = repr(float(c) / 2.0)
    return f"{half} {half} {c}"


def _longest_step_s(p: TestbedParams, fixtures) -> float:
    """The longest physics step [s] of the accurate rule over ``fixtures`` (whatever simulation.substeps_rule)."""
    return max(physics_timestep(p, fixture, "accurate")[0] for fixture in fixtures)


def _step_lengthening_fields(p: TestbedParams, fixtures) -> list[str]:
    """``group.field = value (default d)`` of every field that differs from the defaults and, set back to its
    default alone, gives a shorter physics step in ``fixtures``."""
    default, h = type(p)(), _longest_step_s(p, fixtures)  # the defaults of p's own parameter class
    found = []
    for name, value, unit, _ in p.rows():
        group, field = name.split(".")
        base = getattr(getattr(default, group), field)
        if value == base or (group, field) in SOLVER_TIME_CONSTANTS:
            continue
        try:
            reverted = p.replace(**{group: {field: base}})
        except ParameterError:  # the field cannot go back alone (a constraint between fields)
            continue
        if _longest_step_s(reverted, fixtures) < h:
            unit = "" if unit == "1" else f" {unit}"
            found.append(f"{name} = {value:g}{unit} (default {base:g}{unit})")
    return found


def check_time_constants(p: TestbedParams, fixtures=FIXTURES, source: str | None = None) -> None:
    """Refuse solver time constants shorter than two physics steps of the accurate rule in ``fixtures``.

    The check does not depend on ``simulation.substeps_rule``: under 'fast' the model raises the time constants
    to two of its own, longer steps (``derived.solver_time_constants``), so a parameter set passes for both rules
    or for neither.

    Parameters
    ----------
    p : TestbedParams
        The parameter set.
    fixtures : sequence of str
        The fixtures the parameters are to build (the longest of their physics steps sets the bound).
    source : str, optional
        Where the parameters come from (a file), named in the message as the place to set the values.

    Raises
    ------
    ParameterError
        Naming every time constant below two physics steps, the value each needs, and the fields of ``p`` that
        differ from the defaults and lengthen the step (``physics_timestep``: a higher gear ratio or rotor
        inertia slows the presliding dynamics and so lengthens the step).
    """
    h = _longest_step_s(p, fixtures)
    low = [(group, field, getattr(getattr(p, group), field)) for group, field in SOLVER_TIME_CONSTANTS
           if getattr(getattr(p, group), field) < 2.0 * h * (1.0 - 1e-9)]
    if not low:
        return
    scale = 10.0 ** (math.floor(math.log10(2.0 * h)) - 2)
    needed = math.ceil(2.0 * h / scale - 1e-6) * scale  # two steps rounded up to 3 digits: a value that passes
    n = round(p.simulation.control_period_s / h)
    names = " and ".join(f"{group}.{field} = {value:g} s" for group, field, value in low)
    step = (f"h = {h:.3g} s ({n} physics steps per {p.simulation.control_period_s:g} s control tick; "
            f"models.gim8108_testbed.derived.physics_timestep, accurate rule: the stiffest mode of the drivetrain "
            f"and the presliding time set it)")
    bound = f"valid range [{needed:g}, 1] s, as MuJoCo resolves no constraint faster than two physics steps"
    verb = "is" if len(low) == 1 else "are"
    drivers = _step_lengthening_fields(p, fixtures)
    if drivers:
        message = (f"{', '.join(drivers)} {'lengthens' if len(drivers) == 1 else 'lengthen'} the physics step to "
                   f"{step}, so {names} {verb} too short: {bound}")
    else:
        message = f"{names} {verb} below two physics steps of {step}: {bound}"
    settings = " and ".join(f"[{group}] {field} = {needed:g}" for group, field, _ in low)
    raise ParameterError(f"{message}. Set {settings} in {source if source is not None else 'the parameters'}")


def history_samples(p: TestbedParams, fixture: str) -> int:
    """Samples of the motor actuator's command history [-]: the physics steps of ``motor.command_delay_s``
    plus two spare slots (0 without a delay)."""
    if p.motor.command_delay_s <= 0:
        return 0
    return int(p.motor.command_delay_s / physics_timestep(p, fixture)[0]) + 2


def build_xml(p: TestbedParams, fixture: str, nsample: int | None = None) -> str:
    """MJCF text of the testbed in ``fixture`` ('locked': lever tip on the load cell; 'free': lever turns).

    ``nsample``: samples of the motor's command history, at least :func:`history_samples` (that if None); a
    longer buffer holds older commands the delay never reads, so the run is the same. Models of different
    delays share one data layout with a common ``nsample`` (batched stepping, :mod:`sim.batched`).

    Raises ParameterError for solver time constants the fixture's physics step cannot resolve
    (:func:`check_time_constants`), ValueError for an ``nsample`` below :func:`history_samples`."""
    if fixture not in FIXTURES:
        raise ValueError(f"fixture = {fixture!r}: valid values are {FIXTURES}")
    d = derive(p)
    h, _ = physics_timestep(p, fixture)
    check_time_constants(p, (fixture,))
    solref_s = solver_time_constants(p, fixture)
    n = p.motor.gear_ratio
    fr, fl, lever = p.friction, p.flexure, p.lever
    locked = fixture == "locked"
    k_lc = d.loadcell_rot_stiffness_nm_per_rad if locked else 0.0
    c_lc = d.loadcell_rot_damping_nms_per_rad if locked else 0.0
    half_gap = 0.5 * p.backlash.width_rad
    imp = p.backlash.stop_impedance
    needed = history_samples(p, fixture)
    if nsample is None:
        nsample = needed
    elif nsample < needed or (needed == 0 and nsample != 0):
        raise ValueError(f"nsample = {nsample!r}: valid range [{needed}, inf) for motor.command_delay_s = "
                         f"{p.motor.command_delay_s:g} s (0 without a delay)")
    delay = f'delay="{_f(p.motor.command_delay_s)}" nsample="{nsample}"' if p.motor.command_delay_s > 0 else ""
    ring_r_in = fl.inner_radius_m + fl.beam_length_m
    # Euler's implicit joint damping, off under substeps_rule 'fast' (derived.implicit_joint_damping)
    damping, eulerdamp = ("implicit", "") if implicit_joint_damping(p) else ("explicit", ' eulerdamp="disable"')
    loadcell = (f'<body name="loadcell" pos="{_f(lever.length_m)} {_f(lever.width_m)} 0">'
                f'<geom class="visual" type="box" size="{_f(LOADCELL_HALF_SIZE_M)} {_f(LOADCELL_HALF_SIZE_M)} '
                f'{_f(LOADCELL_HALF_SIZE_M)}" rgba=".2 .5 .8 1"/></body>') if locked else ""
    return f"""<mujoco model="gim8108_testbed_{fixture}">
  <!-- Generated by models/gim8108_testbed/build.py from sim.params; edit the parameters, not this file. -->
  <compiler angle="radian" autolimits="true"/>
  <!-- Euler: semi-implicit with {damping} joint damping. implicit/implicitfast mis-integrate the dcmotor
       LuGre bristle damping while sliding (MuJoCo 4.0.0; see models/gim8108_testbed/README.md). -->
  <!-- PGS: exact for the single backlash-stop row and cheaper than Newton here. The rig has no contacts
       by design (all geoms are visual) and is one kinematic tree: contacts and islands are disabled. -->
  <option timestep="{_f(h)}" integrator="Euler" solver="PGS">
    <flag contact="disable" island="disable"{eulerdamp}/>
  </option>
  <default>
    <geom contype="0" conaffinity="0"/>
    <default class="visual"><geom group="1"/></default>
    <!-- Backlash stops: near-hard limits; solref/solimp tuned (sim.params.BacklashParams). -->
    <default class="backlash_stop">
      <joint solreflimit="{_f(solref_s["backlash", "stop_time_constant_s"])} 1" solimplimit="{_f(imp)} {_f(imp)} 0.001 0.5 2"/>
    </default>
  </default>
  <worldbody>
    <body name="stator">
      <geom class="visual" type="cylinder" size="{_f(fl.outer_radius_m)} {_f(MOTOR_HOUSING_HALF_HEIGHT_M)}"
            pos="0 0 {_f(-MOTOR_HOUSING_HALF_HEIGHT_M)}" rgba=".25 .25 .25 1"/>
      <body name="rotor">
        <!-- Output-referred angle of the gear side of the mesh. Its inertia is the rotor's reflected
             through the gear, N² J_rotor: set here rather than as actuator armature because MuJoCo needs a
             moving body with positive inertia (same dynamics). -->
        <!-- frictionloss: the load-dependent gear friction, set every tick by sim.plant. -->
        <joint name="motor" type="hinge" axis="0 0 1" frictionloss="0"
               solreffriction="{_f(solref_s["friction", "load_friction_time_constant_s"])} 1"
               solimpfriction="{_f(fr.load_friction_impedance)} {_f(fr.load_friction_impedance)} 0.001 0.5 2"/>
        <inertial pos="0 0 0" mass="{_f(p.motor.rotor_mass_kg)}"
                  diaginertia="{_axisymmetric(d.reflected_rotor_inertia_kgm2)}"/>
        <body name="output">
          <joint name="backlash" class="backlash_stop" type="hinge" axis="0 0 1" limited="true"
                 range="{_f(-half_gap)} {_f(half_gap)}"/>
          <inertial pos="0 0 0" mass="{_f(p.flange.mass_kg + d.hub_mass_kg)}"
                    diaginertia="{_axisymmetric(d.output_inertia_kgm2)}"/>
          <geom class="visual" type="cylinder" size="{_f(fl.inner_radius_m)} {_f(0.5 * fl.beam_height_m)}"
                pos="0 0 {_f(0.5 * fl.beam_height_m)}" rgba=".8 .8 .85 1"/>
          <body name="lever">
            <joint name="flexure" type="hinge" axis="0 0 1" stiffness="{_f(d.flexure_stiffness_nm_per_rad)}"
                   damping="{_f(d.flexure_damping_nms_per_rad)}"/>
            <inertial pos="0 0 0" mass="{_f(d.lever_side_mass_kg)}"
                      diaginertia="{_f(0.5 * d.lever_side_inertia_kgm2)} {_f(d.lever_side_inertia_kgm2)} {_f(d.lever_side_inertia_kgm2)}"/>
            <geom class="visual" type="cylinder" size="{_f(fl.outer_radius_m)} {_f(0.5 * fl.beam_height_m)}"
                  pos="0 0 {_f(0.5 * fl.beam_height_m)}" rgba=".7 .7 .75 .6"/>
            <geom class="visual" type="box" pos="{_f(0.5 * lever.length_m)} 0 {_f(fl.beam_height_m + 0.5 * lever.thickness_m)}"
                  size="{_f(0.5 * lever.length_m)} {_f(0.5 * lever.width_m)} {_f(0.5 * lever.thickness_m)}" rgba=".9 .6 .2 1"/>
            <site name="lever_tip" pos="{_f(lever.length_m)} 0 {_f(fl.beam_height_m)}"/>
            <site name="ring_inner" pos="{_f(ring_r_in)} 0 0"/>
          </body>
        </body>
      </body>
    </body>
    {loadcell}
  </worldbody>
  <tendon>
    <!-- Absolute lever angle; in the locked fixture its spring is the load cell (k·L², lever_length m). -->
    <fixed name="lever_angle" stiffness="{_f(k_lc)}" damping="{_f(c_lc)}" springlength="0">
      <joint joint="motor" coef="1"/>
      <joint joint="backlash" coef="1"/>
      <joint joint="flexure" coef="1"/>
    </fixed>
    <!-- Absolute angle of the output flange and hub; its damping is the output bearing's share of the
         viscous drag (friction.output_viscous_share), the rest acts in the gear (the dcmotor's damping). -->
    <fixed name="output_angle" damping="{_f(fr.output_viscous_share * fr.viscous_nms_per_rad)}">
      <joint joint="motor" coef="1"/>
      <joint joint="backlash" coef="1"/>
    </fixed>
  </tendon>
  <actuator>
    <!-- GIM8108 torque-commanded through its driver: input ff = motor-side torque [N·m]. LuGre values are
         motor-side (output value / N, stiffness / N², velocity * N); saturation is 18 N·m / N. -->
    <dcmotor name="motor" joint="motor" gear="{_f(n)}" input="ff"
             motorconst="{_f(p.motor.torque_constant_nm_per_a)} {_f(p.motor.torque_constant_nm_per_a)}"
             resistance="{_f(p.motor.winding_resistance_ohm)}"
             inductance="0 {_f(p.motor.current_loop_time_constant_s)}"
             saturation="{_f(d.motor_peak_torque_motor_side_nm)} 0 0"
             ctrlrange="{_f(-d.motor_peak_torque_motor_side_nm)} {_f(d.motor_peak_torque_motor_side_nm)}"
             damping="{_f((1.0 - fr.output_viscous_share) * fr.viscous_nms_per_rad / n**2)}"
             lugre="{_f(fr.presliding_stiffness_nm_per_rad / n**2)} {_f(d.presliding_damping_nms_per_rad / n**2)} {_f(fr.coulomb_torque_nm / n)} {_f(fr.breakaway_torque_nm / n)} {_f(fr.stribeck_velocity_rad_s * n)}"
             {delay}/>
    <!-- External torque on the lever [N·m]: disturbances and the scripted hand. -->
    <motor name="external" tendon="lever_angle" gear="1"/>
  </actuator>
</mujoco>
"""


def build_model(p: TestbedParams, fixture: str) -> mujoco.MjModel:
    """Compiled MjModel of the testbed."""
    return mujoco.MjModel.from_xml_string(build_xml(p, fixture))


def reference_xml_path(fixture: str) -> Path:
    """Path of the reference XML file of ``fixture``: the default parameters' model."""
    return HERE / f"testbed_{fixture}.xml"
