"""Presliding friction: the LuGre bristle stiffness σ0 (elastic motion before breakaway) differs from the rig's."""

from __future__ import annotations

from sim.discrepancy.effects.base import TESTBED, Effect, Param, reversals

UP = (2.0, 4.0)  # synthetic draws: x σ0, stiffer only (below the rig's, its physics step rule would lengthen the
# step past half the backlash stop's time constant, and the plant refuses the parameter set)
MIN_STUCK_FRACTION = 0.1  # presliding acts while stuck: >= 10 % of the samples stuck
MIN_REVERSALS = 2
RESOLUTION_FRACTION = 0.1  # the encoder must resolve a tenth of the presliding displacement F_s/σ0: at a fifth
# (a 16-bit motor encoder on the testbed) the fit found a stiffer σ0 in 1 of 3 logs and a spurious one in 1 of 25
STIFFNESS_RANGE = (0.01, 100.0)  # fit bound: x the rig's σ0
STARTS = (0.2, 0.5, 2.0, 5.0)  # x the current σ0


class PreslidingFriction(Effect):
    name = "presliding_friction"
    revealing_experiment = "locked_pi_current"
    needs_fine_motor_encoder = True
    description = "elastic (presliding) displacement before breakaway"
    params = (Param("presliding_stiffness", "N·m/rad", "N/m", "LuGre bristle stiffness σ0", neutral=None,
                    fields={"testbed": "friction.presliding_stiffness_nm_per_rad"}, valid=(0.0, 1e9)),)
    rigs = frozenset({TESTBED})
    signature = "motion reversals"
    order = 16

    def bounds(self, key, scale, theta):
        base = scale.baseline["presliding_stiffness"]
        return STIFFNESS_RANGE[0] * base, STIFFNESS_RANGE[1] * base

    def starts(self, model, theta):
        return [{"presliding_stiffness": theta["presliding_stiffness"] * f} for f in STARTS], ()

    def identifiable(self, model, theta):
        stuck = float(model.stuck.mean())
        if stuck < MIN_STUCK_FRACTION:
            return (f"the joint is stuck in only {100 * stuck:.1f} % of the samples (needs "
                    f"{100 * MIN_STUCK_FRACTION:g} %): presliding acts while stuck")
        n = reversals(model.data.velocity, model.stick_velocity)
        if n < MIN_REVERSALS:
            return f"{n} motion reversal(s) in the log (needs {MIN_REVERSALS})"
        displacement = theta["breakaway"] / theta["presliding_stiffness"]
        if model.data.position_resolution > RESOLUTION_FRACTION * displacement:
            return (f"position resolution {model.data.position_resolution:.3g} rad is coarser than "
                    f"{RESOLUTION_FRACTION:g} of the presliding displacement {displacement:.3g} rad")
        return None

    def signature_signal(self, model, theta):
        return model.reversal_indicator()

    def draw(self, rig, rng):
        return {"presliding_stiffness": rig.params.friction.presliding_stiffness_nm_per_rad * float(rng.uniform(*UP))}


EFFECT = PreslidingFriction()
