"""The ECU step as evstab runs it and exports it: the input guard (:mod:`.guard`: bad samples replaced and
counted, faults named in the fault word, the law's authority taken back), then the estimator, the 2-DOF law and
the torque split (:mod:`.step`), written once for numpy and casadi. The loop runs it; the firmware room prints
it as C.
"""
