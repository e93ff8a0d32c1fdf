"""maniskill_pnp.progress: tqdm on a terminal, whole lines (start, at most one per interval, end) in a log."""

from __future__ import annotations

import io
import re
import time

import pytest
from tqdm import tqdm

from maniskill_pnp.progress import DEFAULT_INTERVAL_S, INTERVAL_ENV, LogProgress, log_interval, progress_bar


class Terminal(io.StringIO):
    def isatty(self) -> bool:
        return True


@pytest.fixture(autouse=True)
def default_interval(monkeypatch):
    monkeypatch.delenv(INTERVAL_ENV, raising=False)


def test_log_gets_few_whole_lines_and_the_total_at_the_end():
    log = io.StringIO()
    with progress_bar(total=1000, desc="eval run", unit="ep", file=log) as bar:
        assert isinstance(bar, LogProgress)
        for i in range(1000):
            bar.update()
            bar.set_postfix(grasp=f"{i / 1000:.2f}")
    text = log.getvalue()
    lines = text.splitlines()
    assert "\r" not in text and text.endswith("\n")
    assert 2 <= len(lines) <= 3
    assert lines[0].startswith("eval run:   0% 0/1000")
    assert "100% 1000/1000" in lines[-1] and "ep/s" in lines[-1] and "grasp=1.00" in lines[-1]
    assert "█" not in text  # a line of numbers, not a bar


def test_iteration_and_unknown_total_in_a_log():
    log = io.StringIO()
    assert list(progress_bar(iter(range(7)), desc="scenes", unit="scene", file=log)) == list(range(7))
    lines = log.getvalue().splitlines()
    assert len(lines) == 2 and lines[0].startswith("scenes: 0scene") and lines[-1].startswith("scenes: 7scene")


def test_log_skips_clears_and_cursor_moves():
    log = io.StringIO()
    with progress_bar(total=3, desc="inner", position=1, leave=False, file=log) as bar:
        tqdm.write("a message", file=log)
        bar.update(3)
        bar.set_description("renamed")
    text = log.getvalue()
    assert "\r" not in text and "\x1b" not in text
    lines = text.splitlines()
    assert lines[1] == "a message" and lines[-1].startswith("renamed: 100% 3/3")  # leave=False still ends with a line


def test_terminal_gets_tqdm_as_it_is():
    def output(make) -> str:
        term = Terminal()
        with make(total=1000, desc="eval run", unit="ep", file=term, mininterval=0, miniters=1) as bar:
            for _ in range(1000):
                bar.update()
        assert type(bar) is tqdm
        # times and rates differ from run to run, and with them the blanks that pad a line over a longer one
        return re.sub(r"\[[^]]*\] *", "[times]", term.getvalue())

    text = output(progress_bar)
    assert text == output(tqdm)
    assert text.startswith("\r") and text.count("\r") > 100 and "100%|##########| 1000/1000" in text


def test_interval_from_the_environment(monkeypatch):
    def lines(interval: str) -> list[str]:
        monkeypatch.setenv(INTERVAL_ENV, interval)
        log = io.StringIO()
        with progress_bar(total=10, desc="slow", file=log) as bar:
            for _ in range(10):
                time.sleep(0.02)
                bar.update()
        return log.getvalue().splitlines()

    frequent = lines("0.01")
    assert len(frequent) >= 8 and [line.split()[2] for line in frequent[:3]] == ["0/10", "1/10", "2/10"]
    assert len(lines("1000")) == 2
    assert log_interval() == 1000.0


def test_a_bad_interval_falls_back_to_the_default(monkeypatch):
    monkeypatch.setenv(INTERVAL_ENV, "soon")
    with pytest.warns(UserWarning, match=INTERVAL_ENV):
        assert log_interval() == DEFAULT_INTERVAL_S
    monkeypatch.setenv(INTERVAL_ENV, "-1")
    with pytest.warns(UserWarning):
        assert log_interval() == DEFAULT_INTERVAL_S
