"""The front door stays short and every page it sends a reader to exists."""

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


# README's measured figures: every number in its results sections is a cell of a committed
# results file. A block (bullet, paragraph or table) with a figure cites docs/results/<study>/
# files itself or inherits the citation of the block just before it; each figure must then
# appear, as written, in one of the cited files.
RESULTS_SECTIONS = ('What the results say', 'Does it transfer?')
_STUDY_LINK = re.compile(r'\]\((docs/results/[^)#\s]+)\)')
_FIGURE = re.compile(
    r'(?<![\w.])(?:'
    r'\d+(?:\.\d+)?(?: / \d+(?:\.\d+)?)+'    # per-planner groups: 25 / 0 / 20
    r'|\d+ -> \d+'                            # unattacked -> attacked: 100 -> 80
    r'|x\d+(?:\.\d+)?'                        # ratios: x43
    r'|\d+ of \d+'                            # counts: 4 of 5
    r'|\d+(?:\.\d+)?(?:-\d+(?:\.\d+)?)? ?%'   # percentages and ranges: 4.4 %, 0-0.2 %
    r')(?![\d.]\d)')


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


def unbacked_figures(readme: str, read) -> list[str]:
    """Figures in README's results sections that the results file cited for them does not hold.

    ``read(path)`` returns the text of a repository path (or None when it does not exist)."""
    missing, cited = [], []
    for block in _section_blocks(readme, RESULTS_SECTIONS):
        links = _STUDY_LINK.findall(block)
        cited = links or cited
        figures = _FIGURE.findall(_norm(block))
        if not figures:
            continue
        if not cited:
            missing.append(f'no docs/results/ file cited for: {figures}')
            continue
        texts = [read(path) or '' for path in cited]
        corpus = ' '.join(_norm(t) for t in texts)
        for figure in figures:
            if not re.search(r'(?<![\w.])' + re.escape(figure) + r'(?![\d.]\d)', corpus):
                missing.append(f'{figure!r} not in {cited}')
    return missing


def _read(path: str):
    file = REPO / path
    return file.read_text() if file.is_file() else None


def test_readme_figures_are_in_their_results_files():
    readme = (REPO / 'README.md').read_text()
    assert _section_blocks(readme, RESULTS_SECTIONS), 'README lost its results sections'
    missing = unbacked_figures(readme, _read)
    assert not missing, '\n'.join(missing)


def test_figure_checker_catches_a_figure_its_file_lacks():
    files = {'docs/results/s/README.md': 'PSR 25 / 0 / 20 on 4 of 5 scenes, x43.'}
    readme = ('## What the results say\n\n- It holds on 4 of 5 scenes: 25 / 0 / 20 (x43)\n'
              '  ([s](docs/results/s/README.md)).\n\n| a | 25 / 0 / 20 |\n')
    assert unbacked_figures(readme, files.get) == []
    wrong = readme.replace('25 / 0 / 20 (x43)', '25 / 5 / 20 (x44)')
    assert unbacked_figures(wrong, files.get) == [
        "'25 / 5 / 20' not in ['docs/results/s/README.md']",
        "'x44' not in ['docs/results/s/README.md']"]
    unlinked = '## Does it transfer?\n\nMPlib falls to 10 % on 4 of 5 scenes.\n'
    assert unbacked_figures(unlinked, files.get) == [
        "no docs/results/ file cited for: ['10 %', '4 of 5']"]
    outside = '## Where to read on\n\n40 % somewhere.\n'
    assert unbacked_figures(outside, files.get) == []
