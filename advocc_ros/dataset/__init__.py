"""The certified hard-problem data set (``advocc dataset build``): MotionBenchMaker's problems,
each attacked under the ``solvable`` policy, certified, measured against the victims and
exported again as MotionBenchMaker problems, one Ray task per problem.

Modules: ``problems`` (discovery, split, seeded selection), ``job`` (one problem), ``heatmaps``
(one robot-only heatmap per robot), ``store`` (output layout, resume), ``driver`` (Ray),
``summary`` (per family and split). Import from the module that defines a name.
"""
