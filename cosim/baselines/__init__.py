"""Data-driven baselines trained on a data set of ``cosim dataset``, entering the benchmark as plugins.

Two detectors, each an ``Estimator`` that only diagnoses (``estimates = False``) named by its module
path, as any user's scheme (``cosim benchmark --estimator pca=cosim.baselines.pca:PcaMonitor --params
'pca={model = "models/pca.json"}'``):

- ``cosim.baselines.pca.PcaMonitor`` (the faults track): principal component analysis of the readings,
  Hotelling's T² in the principal subspace and the squared prediction error (SPE, Q) outside it;
- ``cosim.baselines.one_class.OneClassMonitor`` (the attacks track): a one-class Gaussian model of every
  reading id's payload statistics (its value and its change in one tick), scored by Mahalanobis
  distance; a reading that did not come, or came twice, is outside it.

``python -m cosim.baselines.train DATASET [DATASET ...] --out DIR`` fits both on the train split's normal
ticks and sets their limits on the validation split's (``cosim.baselines.train``): one model per plant
(its sensors), in ``DIR/pca.json`` and ``DIR/one_class.json``. numpy only.
"""
