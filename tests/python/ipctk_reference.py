#!/usr/bin/env python3
"""Reference values from ipc-toolkit's Python bindings (ipctk 1.6.1) for tests/contact_ipctk.rs.

Usage:
    ipctk_reference.py validate IN.json OUT.json   # per-configuration quantities
    ipctk_reference.py bench IN.json OUT.json      # timings of the barrier potential on a scene
    ipctk_reference.py trust_region IN.json OUT.json  # OGC trust-region radii and filtered steps

Input and output are JSON written and read by the Rust test; floats round-trip exactly.
All distances are squared, as in ipctk. Nothing here is compared: the Rust side compares.
"""

import json
import sys
import time

try:
    import numpy as np
    import ipctk
except ImportError as err:  # the Rust test reports this clearly
    print(f"ipctk_reference.py: cannot import ipctk/numpy ({err}); "
          "install them with: pip install ipctk==1.6.1 numpy", file=sys.stderr)
    sys.exit(3)

PT = ipctk.PointTriangleDistanceType
EE = ipctk.EdgeEdgeDistanceType


def vecs(xs):
    return [np.array(x, dtype=float) for x in xs]


def point_triangle(cfg):
    p, t0, t1, t2 = vecs(cfg["x"])
    auto = ipctk.point_triangle_distance_type(p, t0, t1, t2)
    ours = getattr(PT, cfg["our_type"])
    out = {"type": auto.name, "distance": ipctk.point_triangle_distance(p, t0, t1, t2)}
    # Derivatives under our type (identical to ipctk's when the types agree), so that ties on
    # region boundaries, where the Hessian legitimately jumps, still compare like with like.
    if not cfg.get("skip_derivatives", False):
        out["distance_typed"] = ipctk.point_triangle_distance(p, t0, t1, t2, ours)
        out["gradient"] = ipctk.point_triangle_distance_gradient(p, t0, t1, t2, ours).tolist()
        out["hessian"] = ipctk.point_triangle_distance_hessian(p, t0, t1, t2, ours).tolist()
    return out


def edge_edge(cfg):
    a0, a1, b0, b1 = vecs(cfg["x"])
    auto = ipctk.edge_edge_distance_type(a0, a1, b0, b1)
    ours = getattr(EE, cfg["our_type"])
    out = {"type": auto.name, "distance": ipctk.edge_edge_distance(a0, a1, b0, b1)}
    if not cfg.get("skip_derivatives", False):
        out["distance_typed"] = ipctk.edge_edge_distance(a0, a1, b0, b1, ours)
        out["gradient"] = ipctk.edge_edge_distance_gradient(a0, a1, b0, b1, ours).tolist()
        out["hessian"] = ipctk.edge_edge_distance_hessian(a0, a1, b0, b1, ours).tolist()
    return out


def mollifier(cfg):
    a0, a1, b0, b1 = vecs(cfg["x"])
    r0, r1, s0, s1 = vecs(cfg["rest"])
    eps_x = ipctk.edge_edge_mollifier_threshold(r0, r1, s0, s1)
    return {
        "eps_x": eps_x,
        "cross": ipctk.edge_edge_cross_squarednorm(a0, a1, b0, b1),
        "value": ipctk.edge_edge_mollifier(a0, a1, b0, b1, eps_x),
        "gradient": ipctk.edge_edge_mollifier_gradient(a0, a1, b0, b1, eps_x).tolist(),
        "hessian": ipctk.edge_edge_mollifier_hessian(a0, a1, b0, b1, eps_x).tolist(),
    }


def barrier(cfg):
    d, dhat = cfg["d"], cfg["dhat"]
    return {
        "value": ipctk.barrier(d, dhat),
        "first": ipctk.barrier_first_derivative(d, dhat),
        "second": ipctk.barrier_second_derivative(d, dhat),
    }


def ccd(cfg):
    x0 = vecs(cfg["x0"])
    x1 = vecs(cfg["x1"])
    accd = ipctk.AdditiveCCD(cfg["max_iterations"], cfg["conservative_rescaling"])
    # Tight Inclusion with no rescaling: a certified lower bound of the true time of impact.
    ti = ipctk.TightInclusionCCD(1e-6, 10000000, 1.0)
    out = {}
    for name, method in (("additive", accd), ("tight_inclusion", ti)):
        fn = method.point_triangle_ccd if cfg["kind"] == "point_triangle" else method.edge_edge_ccd
        hit, toi = fn(*x0, *x1, min_distance=cfg["min_distance"], tmax=1.0)
        out[name] = {"hit": bool(hit), "toi": float(toi) if hit else 1.0}
    return out


def stiffness(cfg):
    barrier_fn = ipctk.ClampedLogBarrier()
    kappa, kappa_max = ipctk.initial_barrier_stiffness(
        cfg["bbox_diagonal"], barrier_fn, cfg["dhat"], cfg["scale"],
        np.array(cfg["grad_energy"]), np.array(cfg["grad_barrier"]), cfg["scale_factor"])
    updated = ipctk.update_barrier_stiffness(
        cfg["prev_min_distance"], cfg["min_distance"], kappa_max, kappa,
        cfg["bbox_diagonal"], cfg["dhat_epsilon_scale"])
    return {"kappa": kappa, "kappa_max": kappa_max, "updated": updated}


def scene_setup(scene):
    V = np.asfortranarray(np.array(scene["vertices"], dtype=float))
    F = np.asfortranarray(np.array(scene["faces"], dtype=np.int32))
    E = np.asfortranarray(ipctk.edges(F))
    mesh = ipctk.CollisionMesh(V, E, F)
    potential = ipctk.BarrierPotential(scene["dhat"], scene["stiffness"])
    return V, mesh, potential


def potential(scene):
    V, mesh, pot = scene_setup(scene)
    collisions = ipctk.NormalCollisions()
    collisions.build(mesh, V, scene["dhat"])
    return {
        "active": len(collisions),
        "value": pot(collisions, mesh, V),
        "gradient": pot.gradient(collisions, mesh, V).tolist(),
        "hessian": pot.hessian(collisions, mesh, V).toarray().tolist(),
        "hessian_psd": pot.hessian(
            collisions, mesh, V, ipctk.PSDProjectionMethod.CLAMP).toarray().tolist(),
    }


def validate(data):
    handlers = {
        "point_triangle": point_triangle,
        "edge_edge": edge_edge,
        "mollifier": mollifier,
        "barrier": barrier,
        "ccd": ccd,
        "stiffness": stiffness,
    }
    out = {key: [fn(cfg) for cfg in data[key]] for key, fn in handlers.items()}
    out["potential"] = potential(data["potential"])
    out["version"] = getattr(ipctk, "__version__", "unknown")
    return out


def median_time(fn, reps):
    times = []
    result = None
    for _ in range(reps):
        start = time.perf_counter()
        result = fn()
        times.append(time.perf_counter() - start)
    times.sort()
    return times[len(times) // 2], result


def bench(data):
    scene = data["scene"]
    reps = data["repetitions"]
    V, mesh, pot = scene_setup(scene)
    out = {}
    for threads in data["threads"]:
        ipctk.set_num_threads(threads)
        collisions = ipctk.NormalCollisions()
        t_build, _ = median_time(lambda: collisions.build(mesh, V, scene["dhat"]), reps)
        t_value, value = median_time(lambda: pot(collisions, mesh, V), reps)
        t_grad, grad = median_time(lambda: pot.gradient(collisions, mesh, V), reps)
        t_hess, _ = median_time(lambda: pot.hessian(collisions, mesh, V), reps)
        t_psd, _ = median_time(
            lambda: pot.hessian(collisions, mesh, V, ipctk.PSDProjectionMethod.CLAMP), reps)
        out[str(threads)] = {
            "active": len(collisions),
            "value": value,
            "gradient_norm": float(np.linalg.norm(grad)),
            "build_s": t_build,
            "value_s": t_value,
            "gradient_s": t_grad,
            "hessian_s": t_hess,
            "hessian_psd_s": t_psd,
        }
    return out


def trust_region(data):
    """ipctk.ogc.TrustRegion at each case's positions: its radii, then its filter of dx."""
    out = []
    for case in data["cases"]:
        V = np.asfortranarray(np.array(case["vertices"], dtype=float))
        F = np.asfortranarray(np.array(case["faces"], dtype=np.int32))
        mesh = ipctk.CollisionMesh(V, np.asfortranarray(ipctk.edges(F)), F)
        region = ipctk.ogc.TrustRegion(case["dhat"])
        region.update(mesh, V, ipctk.NormalCollisions())
        dx = np.asfortranarray(np.array(case["dx"], dtype=float))
        region.filter_step(mesh, V, dx)
        out.append({
            "radii": region.trust_region_radii.tolist(),
            "dx": dx.tolist(),
            "should_update": bool(region.should_update_trust_region),
            "relaxed_radius_scaling": region.relaxed_radius_scaling,
        })
    return {"cases": out}


def main():
    modes = {"validate": validate, "bench": bench, "trust_region": trust_region}
    if len(sys.argv) != 4 or sys.argv[1] not in modes:
        print(__doc__, file=sys.stderr)
        sys.exit(2)
    with open(sys.argv[2]) as f:
        data = json.load(f)
    result = modes[sys.argv[1]](data)
    with open(sys.argv[3], "w") as f:
        json.dump(result, f)


if __name__ == "__main__":
    main()
