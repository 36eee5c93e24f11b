"""The browser helper: without a browser a test is skipped locally but fails in CI (CI=true)."""

import browser
import pytest


@pytest.fixture
def no_chromium(monkeypatch):
    monkeypatch.setattr(browser, "_CACHE", {})
    monkeypatch.setattr(browser.shutil, "which", lambda name: None)
    monkeypatch.setattr(browser, "Path", lambda p: type("P", (), {"exists": lambda self: False})())
    monkeypatch.setattr(browser.os, "geteuid", lambda: 1000)  # not root: no install attempt


def test_missing_browser_fails_in_ci(no_chromium, monkeypatch):
    monkeypatch.setenv("CI", "true")
    with pytest.raises(pytest.fail.Exception, match="CI: the browser test cannot run"):
        browser.chromium()


def test_missing_browser_skips_outside_ci(no_chromium, monkeypatch):
    monkeypatch.delenv("CI", raising=False)
    with pytest.raises(pytest.skip.Exception, match="chromium is not installed"):
        browser.chromium()
