"""The front door stays short and every page it sends a reader to exists."""

import csv
import io
import json
import pathlib
import re

REPO = pathlib.Path(__file__).resolve().parents[1]
_LINK = re.compile(r'\]\(([^)#\s]+)(?:#[^)]*)?\)')


def _relative_links(page: pathlib.Path) -> list[str]:
    return [t for t in _LINK.findall(page.read_text()) if '://' not in t]


def test_readme_is_a_front_door():
    lines = (REPO / 'README.md').read_text().splitlines()
    assert len(lines) <= 250, f'README.md has {len(lines)} lines (<= 250: details go to docs/)'
    linked = {pathlib.Path(t).name for t in _relative_links(REPO / 'README.md')}
    missing = sorted(p.name for p in (REPO / 'docs').glob('*.md') if p.name not in linked)
    assert not missing, f'docs pages the README does not link: {missing}'


def test_every_relative_link_resolves():
    pages = [REPO / 'README.md', *sorted((REPO / 'docs').rglob('*.md'))]
    broken = [f'{page.relative_to(REPO)} -> {target}' for page in pages
              for target in _relative_links(page)
              if not (page.parent / target).exists()]
    assert not broken, '\n'.join(broken)


# README's measured figures: every figure in its results sections is a cell of a data file
# (CSV or JSON, written by the tool that measured it) under docs/results/. A block (bullet,
# paragraph or table) with a figure cites those files itself, or inherits the data files of the
# block just before it when it cites nothing under docs/results/; a results README cited for
# its prose backs no figure. A figure is one value or a few: per-planner groups (25 / 0 / 20),
# unattacked -> attacked chains (100 -> 15 -> 0), ranges (0-0.2 %, 3.05-4.02 s), ratios (x43)
# and counts (70 of 70); each value must be a numeric cell of a cited file, rounded as written
# (a percentage may be a fraction cell: 86 % is 0.857), the values of a group, chain or range
# all cells of one column (JSON: one key, or one object's members), a count's two numbers cells
# of one record (a CSV row; a JSON object in a list; a JSON file's own scalar members). Bounds
# (PSR <= 20 %) are claims, not figures.
RESULTS_SECTIONS = ('What the results say', 'Does it transfer?', 'A data set of hard problems')
DATA_SUFFIXES = ('.csv', '.json')
_STUDY_LINK = re.compile(r'\]\((docs/results/[^)#\s]+)\)')
_NUM = r'\d+(?:\.\d+)?'
_FIGURE = re.compile(
    r'(?<![<>=] )(?<![\w.<>=])(?:'
    rf'(?P<group>{_NUM}(?: / {_NUM})+)(?: ?%)?'     # per-planner groups: 25 / 0 / 20
    rf'|(?P<chain>{_NUM}(?: -> {_NUM})+)'           # unattacked -> attacked: 100 -> 80
    rf'|x(?P<ratio>{_NUM})'                         # ratios: x43
    r'|(?P<count>\d+ of \d+)'                       # counts: 4 of 5
    rf'|(?P<percent>{_NUM}(?:-{_NUM})?) ?%'         # percentages and ranges: 4.4 %, 0-0.2 %
    rf'|(?<!x )(?P<seconds>{_NUM}(?:-{_NUM})?) s\b'  # times (not a budget: 20 trials x 5 s)
    r')(?![\d.]\d)')
_SEPARATORS = re.compile(r' / | -> | of |-')


def _norm(text: str) -> str:
    return ' '.join(text.replace('**', '').replace('\\*', '*').split())


def _section_blocks(readme: str, titles: tuple[str, ...]) -> list[str]:
    """The blocks of the sections titled ``titles``: bullets (with their indented lines),
    paragraphs and tables, in order."""
    blocks, current, keep = [], [], False
    for line in readme.splitlines():
        if line.startswith('## '):
            keep = line[3:].strip() in titles
            blocks.append('\n'.join(current))
            current = []
            continue
        if not keep:
            continue
        starts = (not line.strip() or line.startswith('- ')
                  or (line.lstrip().startswith('|') and current
                      and not current[-1].lstrip().startswith('|')))
        if starts and current:
            blocks.append('\n'.join(current))
            current = []
        if line.strip():
            current.append(line)
    blocks.append('\n'.join(current))
    return [b for b in blocks if b.strip()]


class DataCells:
    """The numeric cells of a data file: per column (a CSV column; in JSON a key, and the
    members of one object), and per record (a CSV row; a JSON object that is an element of a
    list, with all it holds)."""

    def __init__(self):
        self.columns: dict[str, list[float]] = {}
        self.records: list[list[float]] = []

    def read(self, path: str, text: str) -> None:
        if path.endswith('.json'):
            data = json.loads(text)
            if isinstance(data, dict):  # the file's own scalar members are a record too
                record: list[float] = []
                for key, value in data.items():
                    if not isinstance(value, (dict, list)):
                        self._add([], value, record)
                self.records.append(record)
            self._walk(path, (), data, None)
            return
        for row in csv.DictReader(io.StringIO(text)):
            record: list[float] = []
            for column, value in row.items():
                self._add([f'{path}:{column}'], value, record)
            self.records.append(record)

    def _add(self, columns: list[str], value, record: list[float] | None) -> None:
        if isinstance(value, bool):
            return
        try:
            number = float(value)
        except (TypeError, ValueError):
            return
        for column in columns:
            self.columns.setdefault(column, []).append(number)
        if record is not None:
            record.append(number)

    def _walk(self, path: str, trail: tuple, node, record: list[float] | None) -> None:
        if isinstance(node, dict):
            for key, value in node.items():
                self._walk(path, (*trail, str(key)), value, record)
        elif isinstance(node, list):
            for value in node:
                element = [] if isinstance(value, dict) else None
                self._walk(path, (*trail, '[]'), value, record if element is None else element)
                if element is not None:
                    self.records.append(element)
                    if record is not None:
                        record.extend(element)
        else:
            key = trail[-1] if trail else ''
            self._add([f'{path}:{key}', f'{path}:{"/".join(trail[:-1])}/'], node, record)


def _matches(written: str, cell: float, percent: bool) -> bool:
    """Whether ``cell`` rounds to the value ``written`` (as a fraction too, for a percentage)."""
    decimals = len(written.partition('.')[2])
    half = 0.5 * 10 ** -decimals + 1e-9
    candidates = (cell, 100 * cell) if percent else (cell,)
    return any(abs(x - float(written)) <= half for x in candidates)


def _backed(kind: str, text: str, cells: DataCells) -> bool:
    """Whether the figure ``text`` of ``kind`` is made of cells (module comment): a count's two
    numbers in one record, the other figures' values in one column."""
    values = [v for v in _SEPARATORS.split(text) if v]
    percent = kind in ('percent', 'group')

    def among(numbers: list[float]) -> bool:
        return all(any(_matches(v, x, percent) for x in numbers) for v in values)

    groups = cells.records if kind == 'count' else cells.columns.values()
    return any(among(numbers) for numbers in groups)


def unbacked_figures(readme: str, read) -> list[str]:
    """Figures in README's results sections that no data file cited for them holds as cells.

    ``read(path)`` returns the text of a repository path (or None when it does not exist)."""
    missing, cited = [], []
    for block in _section_blocks(readme, RESULTS_SECTIONS):
        links = _STUDY_LINK.findall(block)
        if links:
            cited = [link for link in links if link.endswith(DATA_SUFFIXES)]
        figures = [(m.lastgroup, m.group(m.lastgroup), m.group(0))
                   for m in _FIGURE.finditer(_norm(block))]
        if not figures:
            continue
        if not cited:
            missing.append(f'no data file (CSV, JSON) cited for: {[f for *_, f in figures]}')
            continue
        cells = DataCells()
        for path in cited:
            text = read(path)
            if text:
                cells.read(path, text)
        missing += [f'{written!r} not in {cited}' for kind, values, written in figures
                    if not _backed(kind, values, cells)]
    return missing


def _read(path: str):
    file = REPO / path
    return file.read_text() if file.is_file() else None


def test_readme_figures_are_cells_of_their_data_files():
    readme = (REPO / 'README.md').read_text()
    assert _section_blocks(readme, RESULTS_SECTIONS), 'README lost its results sections'
    missing = unbacked_figures(readme, _read)
    assert not missing, '\n'.join(missing)


def test_figure_checker_wants_cells_of_cited_data_files():
    files = {'docs/results/s/psr.csv': 'scene,planner,psr_percent,pt_ratio,time_s\n'
                                       'a,p1,25,43.2,3.05\na,p2,0,7.94,4.02\na,p3,20,,\n',
             'docs/results/s/summary.json': '{"n": 25, "ok": 21, "groups": [{"share": 0.857, '
                                            '"problems": 5, "out": {"built": 5}}, '
                                            '{"problems": 20}], '
                                            '"fewest": {"p1": 10, "p2": 20, "p3": 15}}',
             'docs/results/s/README.md': 'PSR 25 / 5 / 20 and 18 % on 4 of 5 scenes, x44.'}
    readme = ('## What the results say\n\n- It holds: 25 / 0 / 20 (x43, 3.05-4.02 s)\n'
              '  ([psr.csv](docs/results/s/psr.csv)).\n\n| a | 25 -> 0 -> 20 | x7.9 |\n\n'
              'On 86 % of 5 of 5 problems (21 of 25 in all), not PSR <= 10 %, with '
              '10 / 20 / 15 boxes '
              '([summary](docs/results/s/summary.json)).\n')
    assert unbacked_figures(readme, files.get) == []
    wrong = readme.replace('25 / 0 / 20 (x43', '25 / 5 / 20 (x44')
    assert unbacked_figures(wrong, files.get) == [
        "'25 / 5 / 20' not in ['docs/results/s/psr.csv']",
        "'x44' not in ['docs/results/s/psr.csv']"]
    # A value of another column, a count across records, a figure only in prose: not backed.
    mixed = (readme.replace('3.05-4.02 s', '3.05-43.2 s').replace('5 of 5', '20 of 25')
             .replace('10 / 20 / 15', '10 / 20 / 5'))
    assert unbacked_figures(mixed, files.get) == [
        "'3.05-43.2 s' not in ['docs/results/s/psr.csv']",
        "'20 of 25' not in ['docs/results/s/summary.json']",
        "'10 / 20 / 5' not in ['docs/results/s/summary.json']"]
    prose = ('## Does it transfer?\n\nPSR 25 / 5 / 20 and 18 % on 4 of 5 scenes, x44 '
             '([s](docs/results/s/README.md)).\n')
    assert unbacked_figures(prose, files.get) == [
        "no data file (CSV, JSON) cited for: ['25 / 5 / 20', '18 %', '4 of 5', 'x44']"]
    unlinked = '## Does it transfer?\n\nMPlib falls to 10 % on 4 of 5 scenes.\n'
    assert unbacked_figures(unlinked, files.get) == [
        "no data file (CSV, JSON) cited for: ['10 %', '4 of 5']"]
    outside = '## Where to read on\n\n40 % somewhere.\n'
    assert unbacked_figures(outside, files.get) == []
