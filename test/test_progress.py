"""Progress: a tqdm bar on a TTY only; plain periodic lines otherwise."""

import io
import logging

from advocc_ros.progress import LineProgress, progress_bar


class _Tty(io.StringIO):
    def isatty(self):
        return True


def test_a_pipe_gets_plain_lines_without_carriage_returns(monkeypatch):
    out = io.StringIO()
    bar = progress_bar(10, 'bench', 'trial', file=out, interval_s=0.0)
    assert isinstance(bar, LineProgress)
    for _ in range(10):
        bar.update(1)
        bar.set_postfix(psr='1.00')
    bar.write('a log line')
    bar.close()
    bar.close()
    text = out.getvalue()
    assert '\r' not in text
    lines = text.splitlines()
    assert lines[-2].startswith('bench: 10/10 trial (100 %)') and lines[-1] == 'a log line'
    assert len(lines) == 11  # one line per update at interval 0; close repeats nothing
    quiet = io.StringIO()
    with progress_bar(5, 'heatmap', 'q', file=quiet, interval_s=3600.0) as bar:
        bar.update(5)
    assert quiet.getvalue().count('\n') == 1  # only the closing line


def test_a_tty_gets_a_bar_and_log_lines_above_it():
    out = _Tty()
    handlers = list(logging.getLogger().handlers)
    bar = progress_bar(3, 'plans', 'plan', file=out)
    assert not isinstance(bar, LineProgress)
    bar.update(1)
    bar.close()
    assert list(logging.getLogger().handlers) == handlers  # the redirect was undone
    assert '\r' in out.getvalue()


def test_the_closing_line_is_not_repeated():
    out = io.StringIO()
    bar = progress_bar(2, 'heatmap', 'q', file=out, interval_s=0.0)
    bar.update(2)  # prints 2/2
    bar.close()    # nothing new to say
    assert out.getvalue().count('2/2') == 1
