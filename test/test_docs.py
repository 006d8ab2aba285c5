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
