"""Session-scoped fixtures of the taxel-sensor tests: each expensive object is built once."""

import pytest


# ---- taxels-b: opto5 / wire and fingertip25 / fingertip fixtures ------------------------------------------
@pytest.fixture(scope="session")
def wire_result():
    """The quick wire study, seed 0 (``optitact.studies.run``), shared by every test that reads it."""
    from optitact import studies

    return studies.run("wire", seed=0, size="quick")


@pytest.fixture(scope="session")
def fingertip_result():
    """The quick fingertip study, seed 0 (``optitact.studies.run``), shared by every test that reads it."""
    from optitact import studies

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
