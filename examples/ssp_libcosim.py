"""The whole loop as one SSP 1.0 file, run in libcosim: what another co-simulation engine shows.

``uiofmu ssp`` bundles seed 000 Example 1's plant and observer with a C signal source that plays the problem's
``[signals]`` (a sine ``u``, a constant ``d``); libcosim (libcosimpy, from the test extra) loads the ``.ssp``
file and runs it at the observer's default experiment. The plant's state equals our master's at every point;
the estimate libcosim reads carries the ``y`` of the previous point in its direct part (libcosim reads outputs
right after each step, before it passes the new ``y``): the script prints that lag against ``Xy (y_k+1 - y_k)``
and then runs the same bundle with held inputs, where the estimate converges.

    python examples/ssp_libcosim.py          # writes examples/out/ssp_libcosim/
"""

import numpy as np
from _common import OUT, ROOT, design_and_build, main_guard


def run(bundle, plant, observer):
    """The plant's x and the observer's xhat after each step of libcosim, at t_1 .. t_K."""
    from fmpy import read_model_description
    from libcosimpy.CosimExecution import CosimExecution
    from libcosimpy.CosimLogging import CosimLogLevel, log_output_level
    from libcosimpy.CosimObserver import CosimObserver

    log_output_level(CosimLogLevel.ERROR)
    execution = CosimExecution.from_ssp_file(str(bundle.path))
    last = CosimObserver.create_last_value()
    execution.add_observer(observer=last)
    index = {s.name.decode(): s.index for s in execution.slave_infos()}

    def refs(path, name):
        return [v.valueReference for v in read_model_description(str(path)).modelVariables
                if v.name.startswith(f"{name}[")]

    x_refs, xhat_refs = refs(plant, "x"), refs(observer, "xhat")
    x, xhat = [], []
    for _ in range(bundle.steps):
        execution.step(step_count=1)
        x.append(last.last_real_values(slave_index=index["plant"], variable_references=x_refs))
        xhat.append(last.last_real_values(slave_index=index["observer"], variable_references=xhat_refs))
    return np.array(x), np.array(xhat)


def main():
    from uiofmu.cosim.master import cosimulate, load_inputs
    from uiofmu.cosim.ssp import write_ssp

    out = OUT / "ssp_libcosim"
    _, card, observer, plant = design_and_build(ROOT / "examples" / "seed000_example1.toml", out)
    bundle = write_ssp(plant, observer, out / "loop.ssp")
    print(f"{bundle.path}: {len(bundle.connections)} connections, {bundle.steps} steps of "
          f"{bundle.experiment['stepSize']:g} s")
    ours = cosimulate(plant, observer, np.full(bundle.steps, bundle.experiment["stepSize"]))
    x, xhat = run(bundle, plant, observer)
    print(f"plant state, libcosim against our master: largest difference {np.abs(x - ours.x[1:]).max():.3g}")
    lag = ours.xhat[1:] - np.diff(ours.y, axis=0) @ np.asarray(card.matrices["Xy"]).T
    print(f"estimate: libcosim against our master {np.abs(xhat - ours.xhat[1:]).max():.3g}, against our master "
          f"with the y of the previous point in Xy y {np.abs(xhat - lag).max():.3g}")
    print(f"estimate error read in libcosim with the sine input: first {np.linalg.norm(xhat[0] - x[0]):.3g}, "
          f"last {np.linalg.norm(xhat[-1] - x[-1]):.3g}")
    table = out / "held_inputs.csv"
    table.write_text("time,u[1],d[1]\n0,1,0.5\n3,-1,0.5\n", encoding="utf-8")
    held = write_ssp(plant, observer, out / "loop_held.ssp", load_inputs(table, plant, observer))
    x, xhat = run(held, plant, observer)
    print(f"estimate error read in libcosim with held inputs: first {np.linalg.norm(xhat[0] - x[0]):.3g}, "
          f"last {np.linalg.norm(xhat[-1] - x[-1]):.3g}")


if __name__ == "__main__":
    main_guard(main)
