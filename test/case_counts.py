"""Generated-case counts of a fuzz test module, reported and checked after its last test.

A fuzz module counts the cases its tests run in a dict. Reading that dict in a test of its own
makes the check depend on that test running last, which pytest does not promise (``--ff``, a
selection that names it first, a plugin that shuffles). A module-scoped fixture's teardown runs
after the module's last test whatever the order, so the report and the check live there.
"""

import json
import os
import pathlib

COUNTS_ENV = 'ADVOCC_FUZZ_COUNTS'
"""A JSON file the counts are added to, one key per fuzz module (when set)."""


def report_cases(request, kind: str, cases: dict[str, int]) -> int:
    """Print ``cases`` (past pytest's capture) and add them to ``$ADVOCC_FUZZ_COUNTS`` under
    ``kind``; their total."""
    total = sum(cases.values())
    capture = request.config.pluginmanager.getplugin('capturemanager')
    with capture.global_and_fixture_disabled():
        print(f'\nfuzz {kind} cases: {total} {json.dumps(cases, sort_keys=True)}')
    out = os.environ.get(COUNTS_ENV)
    if out:
        path = pathlib.Path(out)
        counts = json.loads(path.read_text()) if path.exists() else {}
        counts[kind] = dict(cases)
        path.write_text(json.dumps(counts, indent=1))
    return total


def whole_module_ran(request, failed_before: int) -> bool:
    """Whether every test function of ``request``'s module was selected in this session and none
    of them failed (``failed_before``: the session's failure count when the module started), so
    the counts are those of a full run."""
    module = request.module
    defined = {name for name, obj in vars(module).items()
               if name.startswith('test_') and callable(obj)}
    selected = {item.originalname for item in request.session.items
                if getattr(item, 'module', None) is module}
    return selected == defined and request.session.testsfailed == failed_before
