"""The design job and what it is made of: the model-error sweep (:mod:`.sweep`), the stability analysis of the
loop with the estimator in it (:mod:`.stability`, :mod:`.analysis`), the worst-case tuning of K_beta, K_gamma and
the filter's noise intensities (:mod:`.tuning`), the limit manoeuvres the tuned design is held to
(:mod:`.limits`), the choice among the tuned designs (:mod:`.selection`), ``evstab design`` itself
(:mod:`.design_job`) and its report (:mod:`.report`); nominal vehicle files for the multi-body cars
(:mod:`.nominal`). It builds on the loop, the verdicts and the kernels.
"""
