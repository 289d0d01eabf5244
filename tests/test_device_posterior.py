"""A fitted device's posterior (issue 23 §4): `wtml device fit` writes what its measurements
left unknown into the device file, and a scene's `spread.posterior` draws devices from it."""

import numpy as np
import pytest

from wtml.bench.device import fit_measured, truth_device
from wtml.decoders.radial import RadialDecoder
from wtml.device_fit import write_device
from wtml.devices import load_device
from wtml.physics.spread import draw_factors
from wtml.scenes import load_scene, scene_from_dict, to_dict
from wtml.schema import SchemaError


@pytest.fixture(scope="module")
def fitted(tmp_path_factory):
    """The hidden device of `wtml bench device` fitted from a sweep and HUE(0) at 1e-4,
    written as a file and read back."""
    start = load_device("micro")
    _, beam = truth_device(start)
    fit = fit_measured(start, beam, "sweep + HUE(0)", 1e-4, np.random.default_rng(0))
    path = write_device(fit.device, tmp_path_factory.mktemp("fit") / "fitted.yaml")
    return fit, path


def test_the_fitted_file_carries_the_fits_covariance_and_draws_it(fitted):
    """The file's posterior is the fit's: relative standard errors and correlations, read
    back unchanged; 20000 devices drawn from it have the fit's relative covariance (to its
    sampling error, ~2 % of each variance) about factor 1."""
    fit, path = fitted
    device = load_device(path)
    post = device.provenance.posterior
    assert post == fit.device.provenance.posterior
    names = list(fit.result.free)
    assert list(post.parameters) == names
    f = np.array([fit.result.factors[k] for k in names])
    want = fit.result.covariance / np.outer(f, f)
    draws = draw_factors(device, {}, 20000, np.random.default_rng(1), posterior=1.0)
    x = np.stack([draws[k] for k in names])
    got = np.cov(x)
    sd = np.sqrt(np.diag(want))
    assert np.all(np.abs(np.diag(got) / np.diag(want) - 1) < 0.05)
    assert np.max(np.abs(got - want) / np.outer(sd, sd)) < 0.05
    assert np.all(np.abs(x.mean(1) - 1) < 0.05 * sd)
    # twice the posterior: four times the covariance
    twice = draw_factors(device, {}, 20000, np.random.default_rng(2), posterior=2.0)
    assert abs(np.var(twice[names[0]]) / (4 * want[0, 0]) - 1) < 0.05


@pytest.mark.parametrize(("edit", "needle"), [
    (lambda p: p | {"correlation": p["correlation"][:-1]}, "need 7 standard_errors and 49"),
    (lambda p: p | {"correlation": [2.0 if i == 1 else c for i, c in
                                    enumerate(p["correlation"])]}, "correlation"),
    (lambda p: p | {"correlation": [0.5 if i == 1 else c for i, c in
                                    enumerate(p["correlation"])]}, "symmetric"),
    (lambda p: p | {"parameters": [p["parameters"][0]] * 7}, "each parameter once"),
])
def test_a_bad_posterior_is_one_line_naming_it(fitted, tmp_path, edit, needle):
    _, path = fitted
    data = to_dict(load_device(path))
    data["provenance"]["posterior"] = edit(data["provenance"]["posterior"])
    import yaml

    bad = tmp_path / "bad.yaml"
    bad.write_text(yaml.safe_dump(data))
    with pytest.raises(SchemaError, match="provenance.posterior") as err:
        load_device(bad)
    assert needle in str(err.value) and len(str(err.value).splitlines()) == 1


def test_a_posterior_spread_needs_a_fitted_device():
    base = to_dict(load_scene("configs/scenes/radial.yaml"))
    with pytest.raises(SchemaError, match=r"spread.posterior: device 'micro' holds no fit "
                                          r"posterior"):
        scene_from_dict(base | {"spread": {"posterior": 1.0}})


def test_records_over_the_posterior_differ_by_what_the_fit_left_unknown(fitted):
    """On the fitted device with `spread.posterior: 1`, each record's free reference differs
    from the fitted device's by more than its own noise (2e-6) and far less than the
    manufacturing spread moves it (~1e-2); the radial decoder then reads the ratio Ze/ref
    only, not the reference's own values, and its domain gate reads the devices' deviations."""
    _, path = fitted
    base = to_dict(load_scene("configs/scenes/radial.yaml"))
    scene = scene_from_dict(base | {"device": str(path), "spread": {"posterior": 1.0,
                                                                   "devices": 64}})
    one = scene_from_dict(base | {"device": str(path)})
    r = scene.simulate(2000, np.random.default_rng(0))
    dev = np.median(np.abs(r["ref"] / one.free_ze() - 1))
    noise = np.median(np.abs(one.simulate(2000, np.random.default_rng(0))["ref"]
                             / one.free_ze() - 1))
    assert 2 * noise < dev < 1e-3  # measured: 4.8e-6 against the noise's 1.7e-6
    assert not scene.spread.tolerances and not scene.spread.none
    module = RadialDecoder(hidden=[8], refine_hidden=None)
    import torch

    tensors = [torch.tensor(p, dtype=torch.float32) for z in (r["ze"], r["ref"])
               for p in (z.real, z.imag)] + [torch.tensor(r["distance"][:, None],
                                                          dtype=torch.float32)]
    net = module.build_net(scene, *tensors)
    assert net.device is False
    _, n_feat = module.domain_features(scene)
    _, n_one = module.domain_features(one)
    assert n_feat > n_one


def test_a_posterior_too_wide_or_on_the_wrong_device_is_refused(fitted, tmp_path):
    """Factors drawn Gaussian must stay far from 0: `spread.posterior` times the widest
    relative standard error is at most 0.2. A posterior naming a parameter the device cannot
    build is refused by the scene, and a lumped device holds none."""
    import dataclasses

    import yaml

    from wtml.devices import Posterior

    _, path = fitted
    device = load_device(path)
    base = to_dict(load_scene("configs/scenes/radial.yaml"))
    post = device.provenance.posterior
    wide = dataclasses.replace(post, standard_errors=tuple(
        se if name == "whisker.length" else 0.05
        for name, se in zip(post.parameters, post.standard_errors, strict=True)))
    loose = dataclasses.replace(device, provenance=dataclasses.replace(device.provenance,
                                                                      posterior=wide))
    scene_from_dict(base | {"device": to_dict(loose), "spread": {"posterior": 4.0}})
    with pytest.raises(SchemaError, match=r"spread.posterior: 5 times bimorph.length's relative "
                                          r"standard error is 0.25; a Gaussian draw"):
        scene_from_dict(base | {"device": to_dict(loose), "spread": {"posterior": 5.0}})
    odd = dataclasses.replace(device, provenance=dataclasses.replace(
        device.provenance, posterior=Posterior(("tip_mass",), (1e-3,), (1.0,))))
    with pytest.raises(SchemaError, match=r"posterior names 'tip_mass', not one of its"):
        scene_from_dict(base | {"device": to_dict(odd), "spread": {"posterior": 1.0}})
    lumped = to_dict(load_device("fluid-lumped"))
    lumped["provenance"]["posterior"] = {"parameters": ["k"], "standard_errors": [0.01],
                                         "correlation": [1.0]}
    (tmp_path / "lumped.yaml").write_text(yaml.safe_dump(lumped))
    with pytest.raises(SchemaError, match=r"provenance.posterior: a lumped device has no fit "
                                          r"posterior"):
        load_device(tmp_path / "lumped.yaml")
    with pytest.raises(ValueError, match="holds no fit posterior"):
        draw_factors(load_device("micro"), {}, 3, np.random.default_rng(0), posterior=1.0)
