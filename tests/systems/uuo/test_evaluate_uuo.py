"""Scoring UUO solves against the studio's truth: which prior a solve started from."""

from __future__ import annotations

from types import SimpleNamespace

from mocapflow.systems.uuo.evaluate import prior_of


def test_each_solve_is_scored_with_the_prior_it_started_from():
    def stage(output, **inputs):
        return SimpleNamespace(spec=SimpleNamespace(output=output), inputs=inputs)

    catalog = SimpleNamespace(stages={
        "markers": stage("raw_markers"), "segments": stage("marker_segments", markers="markers"),
        "prior": stage("body_prior", markers="markers"), "prior_b": stage("body_prior", markers="markers"),
        "priors": stage("body_prior", prior0="prior", prior1="prior_b", prior2="prior"),
        "screen": stage("uuo_screen", markers="markers", segments="segments", prior="prior"),
        "h0": stage("uuo_body", markers="markers", segments="segments", prior="prior", screen="screen"),
        "body": stage("uuo_body", markers="markers", h0="h0", h1="h0", h2="h0", h3="h0"),
        "p0": stage("uuo_body", markers="markers", segments="segments", prior="priors", screen="screen"),
        "body3": stage("uuo_body", markers="markers", h0="p0", h1="p0", h2="p0", h3="p0"),
        "alone": stage("uuo_body", markers="markers"),
    })
    assert prior_of(catalog, "body") == "prior"
    assert prior_of(catalog, "body3") == "priors"  # the combined prior, not the draws behind it
    assert prior_of(catalog, "alone") is None
