"""Adam with bias correction (Kingma and Ba 2014; thesis eq. 2.38-2.39).

    m_n = b1 m_{n-1} + (1 - b1) g_n,   v_n = b2 v_{n-1} + (1 - b2) g_n^2
    y_{n+1} = y_n - lr m_n / (1 - b1^n) / sqrt(v_n / (1 - b2^n) + eps)

eq. 2.39's epsilon sits inside the square root, so it must stay far below the squared gradients: the
teeth loss is a mean over pixels, and near the optimum its gradients are 1e-6 to 3e-5; 1e-8 (the usual
default) made sqrt(eps) = 1e-4 the divisor, and Adam plain gradient descent there.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

B1 = 0.9
B2 = 0.999
EPS = 1e-24


@dataclass
class Adam:
    lr: float
    b1: float = B1
    b2: float = B2
    eps: float = EPS
    m: np.ndarray | None = None
    v: np.ndarray | None = None
    n: int = 0

    def step(self, y: np.ndarray, g: np.ndarray, lr: float | np.ndarray | None = None) -> np.ndarray:
        if self.m is None:
            self.m = np.zeros_like(y)
            self.v = np.zeros_like(y)
        self.n += 1
        self.m = self.b1 * self.m + (1 - self.b1) * g
        self.v = self.b2 * self.v + (1 - self.b2) * g * g
        mh = self.m / (1 - self.b1**self.n)
        vh = self.v / (1 - self.b2**self.n)
        return y - (self.lr if lr is None else lr) * mh / np.sqrt(vh + self.eps)
