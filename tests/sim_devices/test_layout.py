"""sim_devices mirrors drivers/: a sub-package per device family, few modules at the top."""

from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]


def test_every_driver_family_has_its_simulated_peer_package():
    families = {p.name for p in (ROOT / "drivers").iterdir() if (p / "driver.py").is_file()}
    assert families >= {"fpsa", "awg", "digitizer", "controller"}
    for fam in families:
        pkg = ROOT / "sim_devices" / fam
        assert (pkg / "__init__.py").is_file() and (pkg / "device.py").is_file(), fam


def test_few_modules_sit_directly_in_sim_devices():
    top = sorted(p.name for p in (ROOT / "sim_devices").glob("*.py") if p.name != "__init__.py")
    assert len(top) <= 12, top
