"""MPM AD gradient against central differences near the stand/fail threshold of a column.

An undrained (phi = 0, no tension) column 16 m wide and 28 m tall on fixed ground, 4 m cells,
112 moving points, 30 frames (1.1 s); target: the run at c = 300 kPa; loss: mean squared
distance to the target at frame 30. For c from 200 to 280 kPa the column deforms less and
less (a no-tension Tresca cut stands to about H = 2 c / gamma, i.e. c = 250 kPa for 28 m):
AD gradient against FD with steps of 1 and 0.1 kPa.

    .venv/bin/python bench/mpm_ad_threshold.py
"""

from __future__ import annotations

import torch

from runout.mpm.differentiable import DifferentiableMpm
from runout.scene import scene_from_dict

COLUMN = {
    "domain": {"width": 60.0, "height": 40.0}, "time": {"frames": 31},
    "materials": {"soil": {"friction_angle": 0.0, "cohesion": 100.0}, "ground": {"model": "elastic"}},
    "regions": [{"material": "ground", "polygon": [[0, 0], [60, 0], [60, 2], [0, 2]], "fixed": True},
                {"material": "soil", "polygon": [[10, 2], [26, 2], [26, 30], [10, 30]]}],
}


def main() -> None:
    torch.set_num_threads(1)
    model = DifferentiableMpm(scene_from_dict(COLUMN, "column"), [30])
    start = model.template.index_put((model.moving_index,), model.start["x"])
    phi = torch.zeros(2, dtype=torch.float64)

    def run(c: float, grad: bool = False):
        cc = torch.tensor([c, 0.0], dtype=torch.float64, requires_grad=grad)
        with torch.set_grad_enabled(grad):
            return model(phi, cc)[-1], cc

    target = run(300.0)[0]

    def loss(p):
        return (p - target).square().sum(1).mean()

    print("| c (kPa) | loss (m^2) | max displacement (m) | AD (m^2/kPa) | FD 1 kPa | FD 0.1 kPa |")
    print("|---|---|---|---|---|---|")
    for c in (200.0, 240.0, 250.0, 260.0, 280.0):
        p, cc = run(c, True)
        value = loss(p)
        value.backward()
        fd = [(float(loss(run(c + h)[0])) - float(loss(run(c - h)[0]))) / (2 * h) for h in (1.0, 0.1)]
        moved = float((p.detach() - start).norm(dim=1).max())
        print(f"| {c:g} | {float(value.detach()):.4g} | {moved:.3f} | {float(cc.grad[0]):.4g} | {fd[0]:.4g} | {fd[1]:.4g} |", flush=True)


if __name__ == "__main__":
    main()
