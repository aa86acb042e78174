"""The stability loop, closed in one place: sensors, the ECU step (the firmware's or a variant,
:mod:`.loop_ecu`; a fault injected into one of its inputs, :mod:`.ecu_faults`), actuators and plant in
:func:`.closed_loop.loop_step`, its compiled program (:mod:`.loop_program`), the simulator that runs manoeuvres
through it (:mod:`.simulator`) and the figures of a run (:mod:`.plotting`).
"""
