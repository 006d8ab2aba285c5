"""``make fuzz``: thousands of generated malformed inputs against every parser and live node.

Run as ``python -m fuzz`` with ``test/`` on ``PYTHONPATH`` (the Makefile does this). It lives
beside the tests, not in the package: it needs test data (``test/data/mbm``), rclpy for the
live nodes (which stage packages may not import) and is a development tool, not something a
user of the installed package runs. Inputs come from a seeded generator of our own rather than
hypothesis: each input is rebuilt from ``(seed, family, index)`` alone, so a worker process
generates it, and a crash or hang can be written out again and replayed without shrinking.

Each input is classified (see :mod:`fuzz.classify`) as ``ok``, ``clear_error``,
``unclear_error``, ``accepted_bad``, ``crash`` or ``hang``; ``crash``, ``hang`` and
``accepted_bad`` make the run fail.
"""
