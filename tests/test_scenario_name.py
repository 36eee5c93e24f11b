"""A shipped scenario's name still names it when a folder of that name is in the working directory (a user's
``hqp-tpm run lwr_relaxed --out lwr_relaxed``, run again, read "scenario file not found: 'lwr_relaxed'")."""

import pytest

from hqp_tpm.app.scenario import SCENARIO_DIR, resolve_path
from hqp_tpm.errors import ScenarioError


def test_a_folder_named_like_a_scenario_does_not_hide_it(tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    (tmp_path / "lwr_relaxed").mkdir()
    (tmp_path / "mine").mkdir()
    assert resolve_path("lwr_relaxed") == SCENARIO_DIR / "lwr_relaxed.toml"
    with pytest.raises(ScenarioError, match=r"'mine' is a folder, not a scenario file; unknown scenario 'mine'; "
                                            r"scenarios in .*lwr_relaxed"):
        resolve_path("mine")
    with pytest.raises(ScenarioError, match="scenario file not found: 'gone.toml'"):
        resolve_path("gone.toml")
    (tmp_path / "own.toml").write_text("")
    assert resolve_path("own.toml").resolve() == tmp_path / "own.toml"
