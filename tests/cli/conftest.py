"""The generated lab-like dataset the lab commands' tests share (histostudy.study.your_data.lab_dataset;
seed 5, a 2-frame cine), made once per test process, and its synthetic truth."""

import json

import numpy as np
import pytest

from histostudy.study.your_data.lab_dataset import write_lab_dataset


@pytest.fixture(scope="session")
def lab(tmp_path_factory):
    return write_lab_dataset(tmp_path_factory.mktemp("lab"), seed=5, n_cine_frames=2)


@pytest.fixture(scope="session")
def truth(lab):
    return {k: np.asarray(v) if isinstance(v, list) else v for k, v in json.loads(lab.truth.read_text()).items()}
