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


# ---- taxels-b: opto5 / wire and fingertip25 / fingertip fixtures ------------------------------------------
@pytest.fixture(scope="session")
def wire_result():
    """The quick wire study, seed 0 (``optitact.studies.run``), shared by every test that reads it."""
    return studies.run("wire", seed=0, size="quick")


@pytest.fixture(scope="session")
def fingertip_result():
    """The quick fingertip study, seed 0 (``optitact.studies.run``), shared by every test that reads it."""
    return studies.run("fingertip", seed=0, size="quick")


@pytest.fixture(scope="session")
def opto5_clean():
    """A noise-free opto5 (ADC quantisation only), its normalisation and the closure's largest stimulus."""
    from optitact.taxels.opto5 import Opto5, Opto5Config
    from optitact.taxels.wire import NormalisationLUT, calibration_closure

    src = Opto5(Opto5Config(noise_v=0.0, repeatability=0.0))
    dv, stim = calibration_closure(src, seed=0)
    return src, NormalisationLUT.from_closure(dv, stim), stim.max()


@pytest.fixture(scope="session")
def fingertip_quiet():
    """Noise- and scatter-free fingertip without crosstalk: threshold, quantisation and saturation remain."""
    from optitact.taxels.fingertip25 import Fingertip25, Fingertip25Config

    return Fingertip25(Fingertip25Config(noise_n=0.0, repeatability=0.0, crosstalk=0.0))
# ---- end of taxels-b fixtures -------------------------------------------------------------------------------
