"""What a run is judged by: FMVSS 126's sine with dwell and its criteria (:mod:`.fmvss126`), the envelope of
named manoeuvres with its rules (:mod:`.envelope`), and the robustness scenarios the estimators are scored on
(:mod:`.estimators`). They run the simulator and nothing above it.
"""
