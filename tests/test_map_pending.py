"""The evidence computed beside other work (``find_map(defer_evidence=True)``,
``inference/map/_pending``) is the evidence of the sequential search, bit for bit.

The posterior is the harmonic oscillator of ``test_map_evidence.py`` (one coefficient, a
process and an observation variance, both integrated by the quadrature). The reference is
``find_map`` without deferring; the deferred evidence is finished three ways: in a background
thread while this thread runs other compiled work on the same posterior (another MAP search,
as the sampler would), and in the caller without a thread. Cancelled, it keeps the Laplace
stand-in; an error of the computation is raised. (A whole fit, whose evidence is computed
beside its sampler, is compared with the sequential search in ``test_fit_diagnostics.py``.)
"""

from __future__ import annotations

import json

import numpy as np
import pytest

from symplid import find_map
from symplid.inference.map._pending import EvidenceCancelled
from symplid.inference.map._result import MapResult
from test_map_evidence import oscillator


def _without_seconds(evidence: dict) -> dict:
    return {k: v for k, v in evidence.items() if k != "seconds"}


@pytest.fixture(scope="module")
def posterior():
    return oscillator(0.1)


@pytest.fixture(scope="module")
def sequential(posterior):
    return find_map(posterior, num_starts=1, warn=False)


def _same_evidence(result: MapResult, reference: MapResult) -> None:
    assert result.pending is None
    assert result.evidence_method == reference.evidence_method == "quadrature"
    assert result.log_evidence == reference.log_evidence  # the same bits
    assert _without_seconds(result.evidence) == _without_seconds(reference.evidence)
    assert result.log_evidence_laplace == reference.log_evidence_laplace
    np.testing.assert_array_equal(result.theta, reference.theta)


def test_deferred_evidence_in_a_thread_equals_the_sequential_one(posterior, sequential):
    deferred = find_map(posterior, num_starts=1, warn=False, defer_evidence=True)
    np.testing.assert_array_equal(deferred.theta, sequential.theta)
    # meanwhile: the Laplace evidence, saying which rule is still to run
    assert deferred.evidence_method == "laplace"
    assert deferred.evidence == {"deferred": "quadrature"}
    assert deferred.log_evidence == sequential.log_evidence_laplace
    assert json.loads(json.dumps(deferred.to_dict()))["evidence_method"] == "laplace"
    deferred.pending.start()
    # other compiled work on the same posterior while the thread runs (a second search)
    beside = find_map(posterior, num_starts=2, warn=False, evidence="laplace")
    assert np.isfinite(beside.log_posterior)
    _same_evidence(deferred.pending.finish(deferred), sequential)


def test_deferred_evidence_never_started_is_computed_by_finish(posterior, sequential):
    deferred = find_map(posterior, num_starts=1, warn=False, defer_evidence=True)
    _same_evidence(deferred.pending.finish(deferred), sequential)


def test_cancelled_evidence_ends_and_keeps_the_laplace_stand_in(posterior, sequential):
    deferred = find_map(posterior, num_starts=1, warn=False, defer_evidence=True)
    deferred.pending.cancel()
    deferred.pending.start()
    kept = deferred.pending.finish(deferred)
    assert deferred.pending.done
    assert isinstance(deferred.pending._outcome["error"], EvidenceCancelled)
    assert kept.pending is None and kept.evidence_method == "laplace"
    assert kept.log_evidence == sequential.log_evidence_laplace
    assert kept.evidence == {"deferred": "quadrature"}


def test_an_error_of_the_computation_is_raised_by_finish(posterior):
    deferred = find_map(posterior, num_starts=1, warn=False, defer_evidence=True)
    pending = deferred.pending
    pending._vg = None  # not callable: the computation fails at its first evaluation
    pending.start()
    with pytest.raises(TypeError):
        pending.finish(deferred)


def test_nothing_is_deferred_where_the_evidence_is_laplaces(posterior):
    result = find_map(posterior, num_starts=1, warn=False, evidence="laplace",
                      defer_evidence=True)
    assert result.pending is None and result.evidence_method == "laplace"
