"""Session fixtures of the taxel tests: sources and quick study results, each built once.

The quick study results go through ``optitact.studies.run`` (and its result
cache), so the notebooks reuse them.
"""

import pytest

from optitact import studies


# ---- taxels-a: piezo16, thread8, the tracing and palpation studies -------------------------------------
@pytest.fixture(scope="session")
def piezo16_source():
    """The default piezo16 pad."""
    from optitact.taxels.piezo16 import Piezo16

    return Piezo16()


@pytest.fixture(scope="session")
def piezo16_ideal():
    """No readout noise, no gain spread: outputs follow the law exactly."""
    from optitact.taxels.piezo16 import Piezo16, Piezo16Config

    return Piezo16(Piezo16Config(noise_v=0.0, unit_gain_spread=0.0))


@pytest.fixture(scope="session")
def thread8_source():
    """The default thread8 array."""
    from optitact.taxels.thread8 import Thread8

    return Thread8()


@pytest.fixture(scope="session")
def tracing_result():
    """``studies.run("tracing", seed=0, size="quick")``."""
    return studies.run("tracing", seed=0, size="quick")


@pytest.fixture(scope="session")
def palpation_result():
    """``studies.run("palpation", seed=0, size="quick")``."""
    return studies.run("palpation", seed=0, size="quick")
