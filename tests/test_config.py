"""The hardware-file loader: every problem is reported with file, key path and reason."""

import pytest

from tcs.config import DEFAULT_CONFIG, load_config, parse_config
from tcs.config.passwords import hash_password, verify_password
from tcs.errors import ConfigErrors


def problems(text: str) -> list[str]:
    with pytest.raises(ConfigErrors) as info:
        parse_config(text, "bad.toml")
    return [e.message for e in info.value.errors]


def test_default_file_is_the_simulated_telescope():
    config = load_config()
    assert config.source == DEFAULT_CONFIG
    assert config.server.host == "127.0.0.1" and config.server.port == 65432
    assert [u.name for u in config.users] == ["admin"]
    assert verify_password("admin", config.users[0].password)


@pytest.mark.parametrize("text, expected", [
    ("[server]\nprot = 1\n", "bad.toml: server.prot: unknown key"),
    ("[server]\nport = \"x\"\n", "bad.toml: server.port: must be an integer"),
    ("[server]\nport = 70000\n", "bad.toml: server.port: 70000 is out of range"),
    ("[server]\nline_ending = \"CR\"\n", "bad.toml: server.line_ending: must be one of"),
    ("[[users]]\nname = \"a\"\npassword = \"secret\"\n", "bad.toml: users[0].password: must be a salted hash"),
    ("[[users]]\npassword = \"x\"\n", "bad.toml: users[0].name: missing"),
    ("[site]\nlatitude = 91\n", "bad.toml: site.latitude: 91.0 is out of range"),
    ("[mount]\ntype = \"RA-DEC\"\noptions = [\"AZ-ZD\"]\n", "bad.toml: mount.type: 'RA-DEC' is not among"),
    ("[server]\nimplicit_auth = true\n", "bad.toml: server.implicit_user: implicit_auth needs"),
    ("server = [", "bad.toml: not valid TOML"),
])
def test_problem_is_named(text, expected):
    assert any(p.startswith(expected) for p in problems(text)), problems(text)


def test_all_problems_reported_at_once():
    found = problems("[server]\nport = -1\nhost = 3\n[site]\nheight = \"high\"\n")
    assert len(found) == 3


def test_duplicate_users_refused():
    h = hash_password("x", iterations=1000)
    text = f'[[users]]\nname="a"\npassword="{h}"\n[[users]]\nname="a"\npassword="{h}"\n'
    assert any("duplicate user 'a'" in p for p in problems(text))


def test_missing_file_is_a_clear_error(tmp_path):
    with pytest.raises(ConfigErrors, match="cannot read"):
        load_config(tmp_path / "nope.toml")
