"""The per-step Numba kernel of the scene: what Box2D 2.3's island solver does with the springs
and the walls (b2DistanceJoint, b2ContactSolver, b2Island::Solve's clamps, b2World::SolveTOI).

Private to :mod:`tpnet_ref.sim.scene`, which imports it on the first step. numba is the ``sim``
extra: without it, importing this module raises one line naming the extra.
"""
from __future__ import annotations

import math

import numpy as np

from ..extras import require

numba = require("numba", "sim")


@numba.njit(cache=True, fastmath=False)
def advance(pos, vel, ang, out_pos, lam, wl_n, wl_t, ia, ib, rest, inv_mass, h, omega,
            zeta, iters, slop, max_tr, max_rot, walls, toi, lo, hi, face_lo, face_hi, touch,
            radius, toi_stop, mass, inertia, mu, e_wall, v_thresh):  # pragma: no cover
    """One Box2D island step for the springs and walls, in place.

    Springs (soft distance joints) and wall contacts solved together, velocity clamps,
    walls' time of impact, walls' position correction. pos (N, 2) positions now; vel (N, 2),
    ang (N,) velocities after gravity and pymunk's particle-pair contacts, updated to the
    velocities of the step; out_pos (N, 2) receives the positions at the end of the step.
    lam (S,), wl_n / wl_t (N, 4): accumulated spring and wall impulses (warm starting),
    updated. Returns the largest squared linear and angular speeds (for sleeping).

    The constant arguments (:class:`tpnet_ref.sim.scene.Scene` computes them once)::

        ia, ib (S,)       the two particles of each spring
        rest (S,)         the springs' rest lengths
        inv_mass (N,)     the particles' inverse masses
        h                 the time step, s
        omega, zeta       the springs' angular frequency (2 pi frequency) and damping ratio
        iters             velocity iterations
        slop              the contact slop (penetration left uncorrected)
        max_tr, max_rot   the largest translation and rotation per step (0: no clamp)
        walls, toi        whether there are walls, whether their time of impact is solved
        lo, hi            where a centre meets a wall in the time-of-impact solve (the free
                          area's faces moved in by the time-of-impact distance)
        face_lo, face_hi  the walls' inner faces
        touch, radius     the distance at which a particle touches a wall (radius + skin), the
                          particles' radius
        toi_stop          the distance from the face at which an impact leaves a particle
        mass, inertia     a particle's mass and rotational inertia
        mu                the wall contact's friction (geometric mean of the two frictions)
        e_wall, v_thresh  the wall contact's restitution, and the approach speed below which it
                          does not bounce
    """
    n = pos.shape[0]
    s = ia.shape[0]
    ux = np.empty(s)
    uy = np.empty(s)
    bias = np.empty(s)
    gam = np.empty(s)
    meff = np.empty(s)
    # -- wall contacts (b2ContactSolver): a particle touches a wall when its centre is
    #    closer than radius + skin to the face. Restitution bias from the approach
    #    speed before warm starting, then warm start with last step's impulses.
    skin = touch - radius
    nc = 0
    c_i = np.empty(4 * n, np.int64)
    c_k = np.empty(4 * n, np.int64)
    c_nx = np.empty(4 * n)
    c_ny = np.empty(4 * n)
    c_r = np.empty(4 * n)
    c_b = np.empty(4 * n)
    for i in range(n):
        for k in range(4):
            ax = k // 2
            side = k % 2
            gap = pos[i, ax] - face_lo if side == 0 else face_hi - pos[i, ax]
            if walls and gap < touch:
                sg = 1.0 if side == 0 else -1.0
                nx = sg if ax == 0 else 0.0
                ny = sg if ax == 1 else 0.0
                c_i[nc] = i
                c_k[nc] = k
                c_nx[nc] = nx
                c_ny[nc] = ny
                # contact point midway between the surfaces (b2WorldManifold)
                c_r[nc] = 0.5 * (radius + gap - skin)
                vn = vel[i, 0] * nx + vel[i, 1] * ny
                c_b[nc] = -e_wall * vn if vn < -v_thresh else 0.0
                nc += 1
            else:
                wl_n[i, k] = 0.0
                wl_t[i, k] = 0.0
    for c in range(nc):
        i = c_i[c]
        k = c_k[c]
        ln = wl_n[i, k]
        lt = wl_t[i, k]
        vel[i, 0] += (ln * c_nx[c] + lt * c_ny[c]) / mass
        vel[i, 1] += (ln * c_ny[c] - lt * c_nx[c]) / mass
        ang[i] += c_r[c] * lt / inertia
    # -- init velocity constraints + warm start (b2DistanceJoint::InitVelocityConstraints)
    for j in range(s):
        a = ia[j]
        b = ib[j]
        dx = pos[b, 0] - pos[a, 0]
        dy = pos[b, 1] - pos[a, 1]
        length = math.sqrt(dx * dx + dy * dy)
        if length > slop:
            ux[j] = dx / length
            uy[j] = dy / length
        else:
            ux[j] = 0.0
            uy[j] = 0.0
        im = inv_mass[a] + inv_mass[b]
        m = 1.0 / im
        c = length - rest[j]
        d = 2.0 * m * zeta * omega
        k = m * omega * omega
        g = h * (d + h * k)
        g = 1.0 / g if g != 0.0 else 0.0
        gam[j] = g
        bias[j] = c * h * k * g
        meff[j] = 1.0 / (im + g)
        px = lam[j] * ux[j]
        py = lam[j] * uy[j]
        vel[a, 0] -= inv_mass[a] * px
        vel[a, 1] -= inv_mass[a] * py
        vel[b, 0] += inv_mass[b] * px
        vel[b, 1] += inv_mass[b] * py
    # -- sequential impulses: joints, then contacts (b2Island::Solve)
    for _ in range(iters):
        for j in range(s):
            a = ia[j]
            b = ib[j]
            cdot = ux[j] * (vel[b, 0] - vel[a, 0]) + uy[j] * (vel[b, 1] - vel[a, 1])
            imp = -meff[j] * (cdot + bias[j] + gam[j] * lam[j])
            lam[j] += imp
            px = imp * ux[j]
            py = imp * uy[j]
            vel[a, 0] -= inv_mass[a] * px
            vel[a, 1] -= inv_mass[a] * py
            vel[b, 0] += inv_mass[b] * px
            vel[b, 1] += inv_mass[b] * py
        for c in range(nc):
            i = c_i[c]
            k = c_k[c]
            nx = c_nx[c]
            ny = c_ny[c]
            rc = c_r[c]
            tx = ny
            ty = -nx
            # friction first: velocity of the contact point v + w x r, r = -rc n
            vt = (vel[i, 0] + ang[i] * rc * ny) * tx + (vel[i, 1] - ang[i] * rc * nx) * ty
            mt = 1.0 / (1.0 / mass + rc * rc / inertia)
            lim = mu * wl_n[i, k]
            old = wl_t[i, k]
            new = min(max(old - mt * vt, -lim), lim)
            wl_t[i, k] = new
            dl = new - old
            vel[i, 0] += dl * tx / mass
            vel[i, 1] += dl * ty / mass
            ang[i] += rc * dl / inertia
            # then the normal impulse (accumulated >= 0)
            vn = vel[i, 0] * nx + vel[i, 1] * ny
            old = wl_n[i, k]
            new = max(old - mass * (vn - c_b[c]), 0.0)
            wl_n[i, k] = new
            dl = new - old
            vel[i, 0] += dl * nx / mass
            vel[i, 1] += dl * ny / mass
    vmax2 = 0.0
    wmax2 = 0.0
    for i in range(n):
        # -- b2Island::Solve velocity clamps (they change the stored velocity)
        tx = h * vel[i, 0]
        ty = h * vel[i, 1]
        t2 = tx * tx + ty * ty
        if max_tr > 0.0 and t2 > max_tr * max_tr:
            r = max_tr / math.sqrt(t2)
            vel[i, 0] *= r
            vel[i, 1] *= r
        rot = h * ang[i]
        if max_rot > 0.0 and rot * rot > max_rot * max_rot:
            ang[i] *= max_rot / abs(rot)
        v2 = vel[i, 0] * vel[i, 0] + vel[i, 1] * vel[i, 1]
        if v2 > vmax2:
            vmax2 = v2
        if ang[i] * ang[i] > wmax2:
            wmax2 = ang[i] * ang[i]
        # -- move, stopping at the walls' time of impact (b2World::SolveTOI)
        px = pos[i, 0]
        py = pos[i, 1]
        rem = 1.0
        if toi:
            for _ev in range(4):
                best = 2.0
                axis = -1
                sgn = 0.0
                for ax in range(2):
                    p = px if ax == 0 else py
                    v = vel[i, ax]
                    q = p + rem * h * v
                    if v < 0.0 and q < lo:
                        alpha = (p - lo) / (p - q) if p > lo else 0.0
                        if alpha < best:
                            best, axis, sgn = alpha, ax, 1.0
                    elif v > 0.0 and q > hi:
                        alpha = (hi - p) / (q - p) if p < hi else 0.0
                        if alpha < best:
                            best, axis, sgn = alpha, ax, -1.0
                if axis < 0:
                    break
                # advance to the impact
                px += best * rem * h * vel[i, 0]
                py += best * rem * h * vel[i, 1]
                rem *= 1.0 - best
                # Box2D's TOI position solve leaves the particle at toi_stop from the face
                dist = toi_stop
                # contact at the impact: normal n (into the free area), tangent t = (n.y, -n.x)
                nx = sgn if axis == 0 else 0.0
                ny = sgn if axis == 1 else 0.0
                tx = ny
                ty = -nx
                vn = vel[i, 0] * nx + vel[i, 1] * ny
                target = -e_wall * vn if vn < -v_thresh else 0.0
                jn = mass * (target - vn)
                # contact point midway between the two surfaces (b2WorldManifold):
                # r = -(radius + dist - skin) / 2 n; velocity there v + w x r
                rc = 0.5 * (radius + dist - (touch - radius))
                rx = -rc * nx
                ry = -rc * ny
                vcx = vel[i, 0] - ang[i] * ry
                vcy = vel[i, 1] + ang[i] * rx
                vt = vcx * tx + vcy * ty
                rt = rx * ty - ry * tx
                mt = 1.0 / (1.0 / mass + rt * rt / inertia)
                jt = -mt * vt
                lim = mu * jn
                if jt > lim:
                    jt = lim
                elif jt < -lim:
                    jt = -lim
                vel[i, 0] += (jn * nx + jt * tx) / mass
                vel[i, 1] += (jn * ny + jt * ty) / mass
                ang[i] += rt * jt / inertia
                if axis == 0:
                    px = face_lo + dist if sgn > 0 else face_hi - dist
                else:
                    py = face_lo + dist if sgn > 0 else face_hi - dist
                if rem <= 0.0:
                    break
        out_pos[i, 0] = px + rem * h * vel[i, 0]
        out_pos[i, 1] = py + rem * h * vel[i, 1]
        # -- wall position correction (b2ContactSolver::SolvePositionConstraints:
        #    10 iterations, baumgarte 0.2, at most 0.2 per iteration, slop kept)
        if walls:
            for ax in range(2):
                for side in range(2):
                    q = out_pos[i, ax]
                    sep = (q - face_lo if side == 0 else face_hi - q) - touch
                    if sep < -slop:
                        s0 = sep
                        for _it in range(10):
                            corr = 0.2 * (sep + slop)
                            if corr < -0.2:
                                corr = -0.2
                            if corr < 0.0:
                                sep -= corr
                        out_pos[i, ax] = q + (sep - s0 if side == 0 else s0 - sep)
    return vmax2, wmax2


__all__ = ["advance"]
