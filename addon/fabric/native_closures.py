"""The fabric's closure path from Cycles' own nodes: what renders where Open Shading Language does not run.

Cycles without OSL (its default, and every GPU but OptiX) drops script nodes, and every input linked from
one takes its own default value. The "SGGX Fabric" group therefore ends in a Mix Shader ("Shader Path",
:func:`..common.add_osl_switch`) whose factor is linked from the script's ``OSLActive`` output (1 whenever
the script runs) and defaults to 0: with OSL the script's shader (exact lamps + closures) renders, without
it the network built here, which is the shader's closure path (``cycles_osl/ms_sggx_fabric.osl``, the
branch Fast Preview renders) rebuilt node for node:

* fitted mix (``UseFittedClosures`` on, SigmaScale 1, Anisotropy 0; core ``closure_fit``):
  ``k_d diffuse(n) + k_s (w_d diffuse(n) + w_s sheen(n, r_s) + w_v velvet(N_v, s_v) + w_g GGX(N_g, a0)
  + w_v2 velvet(N_v2, s_v2))`` with ``w_j = max(c_j . (p0, p1, p2) + c_jA p3, 0)`` and the view basis
  ``p0 = (1 - mu)^2, p1 = 2 mu (1 - mu), p2 = mu^2, p3 = (1 - mu)(1 + t_w) / 2``;
* otherwise the fixed approximation: ``k_d diffuse(n)`` plus ``k_s / 2`` anisotropic GGX about the flipped
  fibre axis for surface-like flakes (max sigma <= 1), or ``k_s`` microfibre sheen of roughness
  ``clamp(1 / max sigma, 0.05, 1)`` for fibre-like ones.

Cycles' Glossy BSDF takes a roughness R and an anisotropy A, not the two GGX alphas the shader gives:
``alpha = R^2``, and ``alpha_x = alpha (1 - A), alpha_y = alpha / (1 - A)`` for A >= 0 (``alpha_x = alpha /
(1 + A), alpha_y = alpha (1 + A)`` for A < 0). So ``R = (a_x a_y)^(1/4)`` and ``A = 1 - sqrt(a_x / a_y)``
when ``a_x <= a_y``, else ``sqrt(a_y / a_x) - 1`` reproduce any pair with ``a_max / a_min <= 10^4``
(Cycles clamps ``|A| <= 0.99``).
"""

from __future__ import annotations

from ..common import NodeMath

NATIVE_FRAME = "Closures Without OSL"  # the frame holding this network (its presence marks a built group)


def _axes(m: NodeMath, gin, t, b, n):
    """World-space fibre axes (a0, a1, a2) of the normalised basis quaternion (QuatWXY, QuatZ)."""
    tree = m.tree
    q = tree.nodes.new("ShaderNodeSeparateXYZ")
    q.location = (m.x - 200, m.y)
    tree.links.new(gin.outputs["QuatWXY"], q.inputs[0])
    w, x, y, z = q.outputs[0], q.outputs[1], q.outputs[2], gin.outputs["QuatZ"]
    norm2 = m.f("ADD", m.f("ADD", m.f("MULTIPLY", w, w), m.f("MULTIPLY", x, x)),
                m.f("ADD", m.f("MULTIPLY", y, y), m.f("MULTIPLY", z, z)))
    inv = m.f("DIVIDE", 1.0, m.f("SQRT", m.f("MAXIMUM", norm2, 1e-12)))
    w, x, y, z = (m.f("MULTIPLY", c, inv) for c in (w, x, y, z))

    def two(a, b_, sign: str):  # 2 (a0 a1 +/- b0 b1)
        return m.f("MULTIPLY", 2.0, m.f(sign, m.f("MULTIPLY", *a), m.f("MULTIPLY", *b_)))

    def one_minus(p, r):  # 1 - 2 (p^2 + r^2)
        return m.f("SUBTRACT", 1.0, m.f("MULTIPLY", 2.0, m.f("ADD", m.f("MULTIPLY", p, p), m.f("MULTIPLY", r, r))))

    cols = (
        (one_minus(y, z), two((x, y), (w, z), "ADD"), two((x, z), (w, y), "SUBTRACT")),
        (two((x, y), (w, z), "SUBTRACT"), one_minus(x, z), two((y, z), (w, x), "ADD")),
        (two((x, z), (w, y), "ADD"), two((y, z), (w, x), "SUBTRACT"), one_minus(x, y)),
    )
    return tuple(m.v("ADD", m.v("ADD", m.scale(t, cx), m.scale(b, cy)), m.scale(n, cz)) for cx, cy, cz in cols)


def _glossy(m: NodeMath, color, normal, tangent, ax, ay):
    """An anisotropic GGX Glossy BSDF with the alphas ``ax`` (along ``tangent``) and ``ay`` (module docstring)."""
    tree = m.tree
    node = tree.nodes.new("ShaderNodeBsdfGlossy")
    node.distribution = "GGX"
    node.location = (m.x + 400, m.y)
    r = m.f("SQRT", m.f("SQRT", m.f("MULTIPLY", ax, ay)))
    q = m.f("SQRT", m.f("DIVIDE", m.f("MINIMUM", ax, ay), m.f("MAXIMUM", ax, ay)))
    sign = m.f("SUBTRACT", m.f("MULTIPLY", 2.0, m.f("LESS_THAN", ax, ay)), 1.0)
    aniso = m.f("MULTIPLY", sign, m.f("SUBTRACT", 1.0, q))
    for key, sock in (("Color", color), ("Roughness", r), ("Anisotropy", aniso), ("Normal", normal),
                      ("Tangent", tangent)):
        tree.links.new(sock, node.inputs[key])
    return node.outputs[0]


def _sheen(m: NodeMath, distribution: str, color, roughness, normal):
    node = m.tree.nodes.new("ShaderNodeBsdfSheen")
    node.distribution = distribution
    node.location = (m.x + 400, m.y)
    for key, sock in (("Color", color), ("Roughness", roughness), ("Normal", normal)):
        m.tree.links.new(sock, node.inputs[key])
    return node.outputs[0]


def _diffuse(m: NodeMath, color, normal):
    node = m.tree.nodes.new("ShaderNodeBsdfDiffuse")
    node.location = (m.x + 400, m.y)
    node.inputs["Roughness"].default_value = 0.0
    m.tree.links.new(color, node.inputs["Color"])
    m.tree.links.new(normal, node.inputs["Normal"])
    return node.outputs[0]


def _shader(m: NodeMath, kind: str, a, b, fac=None):
    node = m.tree.nodes.new(kind)
    node.location = (m.x + 700, m.y)
    m.y -= 40
    if fac is not None:
        m.tree.links.new(fac, node.inputs[0])
    m.tree.links.new(a, node.inputs[-2])
    m.tree.links.new(b, node.inputs[-1])
    return node.outputs[0]


def _channels(m: NodeMath, color):
    node = m.tree.nodes.new("ShaderNodeSeparateXYZ")
    node.location = (m.x - 200, m.y)
    m.tree.links.new(color, node.inputs[0])
    return node.outputs[0], node.outputs[1], node.outputs[2]


def _tilted(m: NodeMath, n, f2, k):
    """normalize((1 - k) n + k f2)."""
    return m.v("NORMALIZE", m.v("ADD", m.scale(n, m.f("SUBTRACT", 1.0, k)), m.scale(f2, k)))


def build_native_closures(group, gin, location=(-1800, -2200)):
    """Build the closure path inside the fabric ``group`` from its group input node ``gin``; returns the shader
    output socket (module docstring)."""
    tree = group.nodes
    before = {node.name for node in tree}
    frame = tree.new("NodeFrame")
    frame.name = frame.label = NATIVE_FRAME
    m = NodeMath(group, *location)
    geo = tree.new("ShaderNodeNewGeometry")
    geo.location = (location[0] - 300, location[1])
    tangent = tree.new("ShaderNodeTangent")
    tangent.direction_type = "UV_MAP"
    tangent.location = (location[0] - 300, location[1] - 250)
    n, wo = geo.outputs["Normal"], geo.outputs["Incoming"]
    t_raw = tangent.outputs["Tangent"]
    t = m.v("NORMALIZE", m.v("SUBTRACT", t_raw, m.scale(n, m.v("DOT_PRODUCT", t_raw, n))))
    b = m.v("CROSS_PRODUCT", n, t)
    a0, _a1, a2 = _axes(m, gin, t, b, n)

    # sigma with SigmaScale and Anisotropy (the smaller axis shrinks), colours with Tint
    sx = m.f("MAXIMUM", m.f("MULTIPLY", gin.outputs["SigmaX"], gin.outputs["SigmaScale"]), 1e-4)
    sy = m.f("MAXIMUM", m.f("MULTIPLY", gin.outputs["SigmaY"], gin.outputs["SigmaScale"]), 1e-4)
    cut = m.f("MINIMUM", m.f("MAXIMUM", gin.outputs["Anisotropy"], 0.0), 0.95)  # 1 - shrink
    x_smaller = m.f("LESS_THAN", sx, sy)
    sx, sy = (m.f("MULTIPLY", sx, m.f("SUBTRACT", 1.0, m.f("MULTIPLY", x_smaller, cut))),
              m.f("MULTIPLY", sy, m.f("SUBTRACT", 1.0, m.f("MULTIPLY", m.f("SUBTRACT", 1.0, x_smaller), cut))))
    kd = m.v("MULTIPLY", gin.outputs["Kd"], gin.outputs["Tint"])
    ks = m.v("MULTIPLY", gin.outputs["Ks"], gin.outputs["Tint"])

    # fibre axis flipped up, the view basis
    f2 = m.scale(a2, m.f("SUBTRACT", 1.0, m.f("MULTIPLY", 2.0, m.f("LESS_THAN", m.v("DOT_PRODUCT", a2, n), 0.0))))
    mu = m.v("DOT_PRODUCT", wo, n)
    lean = m.v("SUBTRACT", f2, m.scale(n, m.v("DOT_PRODUCT", f2, n)))
    ll = m.v("LENGTH", lean)
    tw = m.f("MULTIPLY", m.f("DIVIDE", m.v("DOT_PRODUCT", wo, lean), m.f("MAXIMUM", ll, 1e-6)),
             m.f("GREATER_THAN", ll, 1e-6))
    one_mu = m.f("SUBTRACT", 1.0, mu)
    basis = tree.new("ShaderNodeCombineXYZ")
    basis.location = (m.x, m.y)
    group.links.new(m.f("MULTIPLY", one_mu, one_mu), basis.inputs[0])
    group.links.new(m.f("MULTIPLY", 2.0, m.f("MULTIPLY", mu, one_mu)), basis.inputs[1])
    group.links.new(m.f("MULTIPLY", mu, mu), basis.inputs[2])
    p3 = m.f("MULTIPLY", m.f("MULTIPLY", one_mu, m.f("ADD", 1.0, tw)), 0.5)

    def weight(name: str):
        coeff = m.v("DOT_PRODUCT", gin.outputs[name], basis.outputs[0])
        alpha = gin.outputs[name + "A"]
        return m.f("MAXIMUM", m.f("ADD", coeff, m.f("MULTIPLY", alpha, p3)), 0.0)

    # fitted mix
    r_s, s_v, k_v = _channels(m, gin.outputs["FitShape"])
    s_v2, k_v2, _ = _channels(m, gin.outputs["FitShape2"])
    k_g = gin.outputs["FitShapeA"]
    ax = m.f("MINIMUM", m.f("MAXIMUM", m.f("MULTIPLY", gin.outputs["FitGGXScale"], sx), 1e-4), 1.0)
    ay = m.f("MINIMUM", m.f("MAXIMUM", m.f("MULTIPLY", gin.outputs["FitGGXScale"], sy), 1e-4), 1.0)
    fitted = _diffuse(m, m.v("ADD", kd, m.scale(ks, weight("FitDiffuse"))), n)
    for lobe in (
        _sheen(m, "MICROFIBER", m.scale(ks, weight("FitSheen")), r_s, n),
        _sheen(m, "ASHIKHMIN", m.scale(ks, weight("FitVelvet")), s_v, _tilted(m, n, f2, k_v)),
        _glossy(m, m.scale(ks, weight("FitGGX")), _tilted(m, n, f2, k_g), a0, ax, ay),
        _sheen(m, "ASHIKHMIN", m.scale(ks, weight("FitVelvet2")), s_v2, _tilted(m, n, f2, k_v2)),
    ):
        fitted = _shader(m, "ShaderNodeAddShader", fitted, lobe)

    # fixed approximation
    smax = m.f("MAXIMUM", sx, sy)
    surface_like = _glossy(m, m.scale(ks, 0.5), f2, a0, sx, sy)
    fibre_like = _sheen(m, "MICROFIBER", ks, m.f("MINIMUM", m.f("MAXIMUM", m.f("DIVIDE", 1.0, smax), 0.05), 1.0), n)
    lobe = _shader(m, "ShaderNodeMixShader", surface_like, fibre_like, fac=m.f("GREATER_THAN", smax, 1.0))
    fixed = _shader(m, "ShaderNodeAddShader", _diffuse(m, kd, n), lobe)

    use_fit = m.f("MULTIPLY", gin.outputs["UseFittedClosures"],
                  m.f("MULTIPLY", m.f("COMPARE", gin.outputs["SigmaScale"], 1.0, 0.0),
                      m.f("COMPARE", gin.outputs["Anisotropy"], 0.0, 0.0)))
    out = _shader(m, "ShaderNodeMixShader", fixed, fitted, fac=use_fit)
    for node in tree:
        if node.name not in before and node.type != "FRAME":
            node.parent = frame
    return out
