"""A Ctrl-C's removal of this process's staging directories (io.staging.remove_active_staging) finds one that was
made but not yet noted. (That it tries again while the main thread still writes into one is a race no test here
provokes reliably: test_hardening_cli's Ctrl-C test left such a directory once in a CI run.)"""

import os

from ntcr_recon.io import staging


def test_a_staging_directory_not_yet_noted_is_found_by_its_name(tmp_path):
    prefix = f".out{staging.STAGING_INFIX}{os.getpid()}-"
    staging._PREFIXES.add(tmp_path / prefix)
    made = tmp_path / f"{prefix}abc123"
    (made / "sub").mkdir(parents=True)
    other = tmp_path / f".out{staging.STAGING_INFIX}{os.getpid() + 1}-abc123"  # another process's: left alone
    other.mkdir()
    try:
        staging.remove_active_staging()
    finally:
        staging._PREFIXES.discard(tmp_path / prefix)
    assert not made.exists() and other.exists()
