"""Record offsets: each record (log) of the rig has its own zero of the effort (and torque sensor) channel.

A torque sensor, or a drive's current sensor, zeroed anew before each record reads the same torque with another
offset in each: a model fitted on one record then misses the next by that difference. With this effect every
joined log carries its own zero, the mean of its effort residual on the sliding samples it is fitted on (its fit
part, or, for a validation log held out whole, the validation log itself), taken out before any other term is
judged. One zero shared by all records is a constant effort (:mod:`sim.discrepancy.effects.constant_effort`): the
records' own zeros are named only where they explain significantly more than one shared constant (rule
'simpler'). The effect is a property of how the records were taken, not of the rig's physics: a simulation of the
rig carries nothing for it.
"""

from __future__ import annotations

from sim.discrepancy.effects.base import Effect, Param, Realisation

MIN_RECORDS = 2


class RecordOffsets(Effect):
    name = "record_offsets"
    revealing_experiment = "free"  # any experiment, recorded more than once
    description = "each record's own zero of the effort (a torque or current sensor zeroed anew before each record)"
    params = (Param("record_offsets", "1", "1", "1: each record has its own zero, fitted on its own samples; 0: the "
                    "records share one", valid=(0.0, 1.0), firm=True),)
    signature = "a constant per record"
    order = 14
    min_records = MIN_RECORDS

    def bounds(self, key, scale, theta):
        return 0.0, 1.0

    def starts(self, model, theta):
        return [{"record_offsets": 1.0}], ("record_offsets",)  # a switch: the zeros themselves are profiled

    def n_parameters(self, model):
        return len(model.records)

    @property
    def stationary_keys(self):
        return ()

    def identifiable(self, model, theta):
        if len(model.records) < MIN_RECORDS:
            return "one record: its zero is a constant effort"
        return None

    def simpler(self, model, theta):
        return "constant_effort", "one zero shared by the records"

    def realise(self, values, rig):
        return Realisation()


EFFECT = RecordOffsets()
