// mnee.glsl: manifold next-event estimation through specular chains (path/trace.comp's
// mnee_estimate and the chain solver under it: chain_trace, leg_clear, chain_at). Included by
// path/trace.comp at the point where it needs it: it reads the trace kernel's event state
// (ev_light, ev_sub, ev_surf_tri, ev_v), its path material (path_mat), the facet lists
// (mnee_cells, mnee_range, mnee_light_inside), the loop budget (iters, iter_limit) and tracking
// (track_start, transmittance_run, trk), all declared before the include.
#ifndef SCATTERLAB_MNEE
#define SCATTERLAB_MNEE

// ---- Specular chains of manifold next-event estimation (src/solvers/mnee.rs) -------------
// A chain is the sequence of facets, from the light's side, at which the light's ray refracts
// or reflects on its way to a scattering point x: one refraction into the object (mesh.glsl
// facet_refraction), or longer ones (light reflected inside before it scatters, light through
// another object or another sheet of a non-convex mesh). The record at word c of mnee_cells:
// k | reflection mask << 8, then the k facets.
const uint CHAIN_MAX = 8u;
// What one chain tried counts against the budget, beyond the loops it runs (which count
// themselves): measured, a full scan (path.mnee_cells=1) counting 1 per chain reached
// llvmpipe's loop limiter at budgets 2000 and up (energy lost: 6-8%), and agreed bit for bit
// with the grid at 1000 and below.
const uint CHAIN_TRY_ITERS = 8u;
vec3 ch_p[CHAIN_MAX];            // the solved chain's vertices, from the light's side
uint ch_mat[CHAIN_MAX + 1u];     // leg l's material where it lies inside an object (leg l ends at vertex l, leg k at x)
uint ch_inside = 0u;             // bit l: leg l lies inside an object (else in vacuum)

// The ray of the light (`point`: a point light at `light`; else travelling along `light`)
// through barycentric coordinates ab of the chain's first facet, followed through its k planes
// (Snell's law or the mirror law at each, as the mask says): the last vertex q, the direction w
// after it, their derivatives with respect to ab (qa, qb, wa, wb: the ray tube, a ray
// differential propagated exactly through flat interfaces), and the product of the Fresnel
// factors (1 - F at a refraction, F at a reflection). False where a refraction meets total
// internal reflection or a plane lies behind the ray.
bool chain_trace(uint c, vec2 ab, vec3 light, bool point, bool light_in, out vec3 q, out vec3 w, out vec3 qa,
                 out vec3 qb, out vec3 wa, out vec3 wb, out float fres) {
    uint head = mnee_cells[c];
    uint k = min(head & 0xffu, CHAIN_MAX), rmask = head >> 8u;
    uint f0 = mnee_cells[c + 1u];
    vec3 e1 = tris[f0].e1.xyz, e2 = tris[f0].e2.xyz;
    q = tris[f0].v0.xyz + ab.x * e1 + ab.y * e2;
    qa = e1;
    qb = e2;
    if (point) {
        vec3 r = q - light;
        float l = length(r);
        w = r / l;
        wa = (e1 - w * dot(w, e1)) / l;
        wb = (e2 - w * dot(w, e2)) / l;
    } else {
        w = light;
        wa = vec3(0.0);
        wb = vec3(0.0);
    }
    fres = 1.0;
    // A light inside an object: the first leg lies in the first facet's object.
    bool in_obj = light_in;
    ch_inside = light_in ? 1u : 0u;
    ch_mat[0] = triangle_material(f0);
    for (uint v = 0u; v < k; v++) {
        LOOP_EDGE(W_CHAIN_PLANES);   // every loop's back-edges count (budget.glsl)
        uint f = mnee_cells[c + 1u + v];
        vec3 n = triangle_normal(f);
        if (v > 0u) {
            // On to facet f's plane: q + t w, t chosen per ray, so its derivative follows.
            float dn = dot(w, n);
            if (dn == 0.0) return false;
            float t = dot(tris[f].v0.xyz - q, n) / dn;
            if (!(t > 0.0)) return false;
            vec3 pa = qa + t * wa, pb = qb + t * wb;
            qa = pa - w * (dot(pa, n) / dn);
            qb = pb - w * (dot(pb, n) / dn);
            q += t * w;
        }
        ch_p[v] = q;
        bool entering = dot(w, n) < 0.0;
        vec3 nf = entering ? n : -n;
        float cos_i = -dot(w, nf);
        float ca = -dot(wa, nf), cb = -dot(wb, nf);
        uint mat = triangle_material(f);
        float ior = scene.materials[mat].ior.x;
        float eta = entering ? 1.0 / ior : ior;
        float cos_t;
        float F = fresnel_dielectric(cos_i, eta, cos_t);
        if (((rmask >> v) & 1u) != 0u) {
            // Mirror: w' = w + 2 cos_i nf.
            fres *= F;
            w += 2.0 * cos_i * nf;
            wa += 2.0 * ca * nf;
            wb += 2.0 * cb * nf;
        } else {
            if (F >= 1.0 || !(cos_t > 0.0)) return false;
            // Snell: w' = eta w + (eta cos_i - cos_t) nf, d cos_t = eta^2 cos_i d cos_i / cos_t.
            fres *= 1.0 - F;
            float s = eta * eta * cos_i / cos_t;
            w = eta * w + (eta * cos_i - cos_t) * nf;
            wa = eta * wa + (eta - s) * ca * nf;
            wb = eta * wb + (eta - s) * cb * nf;
            in_obj = !in_obj;
        }
        if (in_obj) ch_inside |= 1u << (v + 1u);
        ch_mat[v + 1u] = mat;
    }
    return true;
}

// Whether the leg from a to b (in vacuum) is clear of every surface but its ends'.
bool leg_clear(vec3 a, vec3 b) {
    vec3 to = b - a;
    float len = length(to);
    if (!(len > 0.0)) return true;
    float t;
    uint tri;
    float e = surface_eps(a) + surface_eps(b);
    return !mesh_hit_tri(a, to / len, e, len - e, t, tri);
}

// Solves the chain at record c for the point x: where it holds, the vertices (ch_p), the legs
// (ch_inside, ch_mat) and the irradiance E it delivers at x per unit of the light's intensity
// or irradiance (the Fresnel factors times the ray tube's cross-section at the light over its
// cross-section at x: point, dOmega / dA; directional, dA_0 / dA). `check`: the legs in vacuum
// are tested for blockers (the host's flag: several objects or a mesh that is not convex).
// Single refractions by mesh.glsl facet_refraction (bisection on the facet's plane); longer
// chains by Newton's method on the first facet's barycentric coordinates, from its centroid:
// the light's ray through them must pass through x, a 2 x 2 system on the residual
// perpendicular to the last leg (least squares through the ray tube). One solution per chain
// at most: on flat interfaces the optical path length is a convex function of the vertices
// (Fermat), so its stationary point is unique.
bool chain_at(uint c, vec3 x, vec3 light, bool point, bool light_in, bool check, out float E) {
    E = 0.0;
    uint head = mnee_cells[c];
    uint k = head & 0xffu;
    if (k == 0u || k > CHAIN_MAX) return false;
    if (k == 1u && light_in) {
        // A point light reflected once inside its object: the straight line from its mirror
        // image in the facet's plane (a flat mirror keeps the spherical wave: E = F / r^2).
        if ((head >> 8u) == 0u || !point) return false;
        uint f = mnee_cells[c + 1u];
        uint mat = triangle_material(f);
        if (mat != path_mat) return false;
        vec3 n = triangle_normal(f);
        vec3 v0 = tris[f].v0.xyz;
        float hl = dot(light - v0, n), hx = dot(x - v0, n);
        if (!(hl < 0.0 && hx < 0.0)) return false;
        vec3 image = light - 2.0 * hl * n;
        vec3 to = image - x;
        float r2 = dot(to, to);
        // Where x's line to the image crosses the plane.
        vec3 q = x + to * (hx / (hx - (-hl)));
        if (!point_in_triangle(f, q)) return false;
        float cos_i = abs(dot(to, n)) / sqrt(r2);
        float cos_t;
        E = fresnel_dielectric(cos_i, scene.materials[mat].ior.x, cos_t) / r2;
        ch_p[0] = q;
        ch_inside = 3u;
        ch_mat[0] = mat;
        ch_mat[1] = mat;
    } else if (k == 1u) {
        uint f = mnee_cells[c + 1u];
        uint mat = triangle_material(f);
        if (mat != path_mat) return false;
        vec3 ps;
        if (!facet_refraction(f, x, light, point, scene.materials[mat].ior.x, ps, E)) return false;
        ch_p[0] = ps;
        ch_inside = 2u;
        ch_mat[1] = mat;
    } else {
        // The start: where the straight line from the light to x (a directional light's line
        // through x) meets the first facet's plane, clamped onto the facet; its centroid where
        // the line runs along the plane. (From the centroid of a facet many times larger than
        // the light's distance, the first ray can meet total internal reflection.)
        uint f0 = mnee_cells[c + 1u];
        vec3 v0 = tris[f0].v0.xyz, e1 = tris[f0].e1.xyz, e2 = tris[f0].e2.xyz;
        vec2 ab = vec2(1.0 / 3.0);
        {
            vec3 n0 = cross(e1, e2);
            vec3 o0 = point ? light : x;
            vec3 d0 = point ? x - light : light;
            float den = dot(d0, n0);
            vec2 b;
            if (abs(den) > 1e-12 * length(d0) * length(n0) && triangle_coords(f0, o0 + d0 * (dot(v0 - o0, n0) / den), b))
                ab = onto_triangle(b);
        }
        vec3 q, w, qa, qb, wa, wb;
        float fres;
        bool done = false;
        // Converged when x lies within float rounding of the ray: relative to the coordinates'
        // magnitude and to the first facet's (its point is v0 + a e1 + b e2, rounded at that
        // scale: on a facet 17 units long, 1e-5 and more).
        float tol = 4e-6 * (1.0 + max3(abs(x)) + max3(abs(v0)) + length(e1) + length(e2));
        // Where that start's ray meets total internal reflection (x seen beyond the critical
        // angle of a light inside), the foot of a point light on the facet's plane: its ray
        // crosses the first plane along the normal, and most chains through it. A start that
        // went through keeps its trace for the first iteration (traced).
        bool traced = chain_trace(c, ab, light, point, light_in, q, w, qa, qb, wa, wb, fres);
        if (!traced && point) {
            iters++;
            vec3 n0 = normalize(cross(e1, e2));
            vec2 b;
            if (triangle_coords(f0, light - n0 * dot(light - v0, n0), b)) ab = onto_triangle(b);
        }
        // The last coordinates whose ray went through the whole chain: a step into total
        // internal reflection is halved back toward them (near the critical angle the map from
        // the coordinates to the last leg stretches without bound, and full steps overshoot).
        vec2 ab_good = ab;
        bool good = false;
        uint back = 0u;
        for (uint it = 0u; it < 40u; it++) {
            LOOP_EDGE(W_NEWTON);
            bool through = traced || chain_trace(c, ab, light, point, light_in, q, w, qa, qb, wa, wb, fres);
            traced = false;
            if (!through) {
                if (!good || back >= 12u) return false;
                ab = 0.5 * (ab + ab_good);
                back++;
                continue;
            }
            good = true;
            ab_good = ab;
            back = 0u;
            vec3 r = x - q;
            float s = dot(r, w);
            vec3 perp = r - s * w;
            vec3 ja = qa + s * wa, jb = qb + s * wb;
            ja -= w * dot(w, ja);
            jb -= w * dot(w, jb);
            if (dot(perp, perp) <= tol * tol) {
                if (!(s > 0.0)) return false;
                // The ray tube at x (perpendicular to w) and at the light.
                float dA = abs(dot(w, cross(ja, jb)));
                float src;
                if (point) {
                    vec3 r0 = ch_p[0] - light;
                    float l = length(r0);
                    vec3 w0 = r0 / l;
                    src = abs(dot(w0, cross(e1 - w0 * dot(w0, e1), e2 - w0 * dot(w0, e2)))) / (l * l);
                } else {
                    src = abs(dot(light, cross(e1, e2)));
                }
                if (!(dA > 0.0)) return false;
                E = fres * src / dA;
                done = true;
                break;
            }
            float aa = dot(ja, ja), ab2 = dot(ja, jb), bb = dot(jb, jb);
            float ra = dot(ja, perp), rb = dot(jb, perp);
            float det = aa * bb - ab2 * ab2;
            if (!(det > 0.0)) return false;
            vec2 delta = vec2(bb * ra - ab2 * rb, aa * rb - ab2 * ra) / det;
            // The map from ab to the last leg is affine for a directional light (a parallel beam
            // stays parallel through flat interfaces), so one step lands on the solution, and
            // nearly so for a point light over one facet: a full step that lands far outside the
            // facet (half its size beyond an edge) means no solution on it.
            vec2 to = ab + delta;
            if (to.x < -0.5 || to.y < -0.5 || to.x + to.y > 1.5) return false;
            // Damped, for where the beam folds (near a caustic) and a step overshoots.
            float m = max(abs(delta.x), abs(delta.y));
            if (m > 0.5) delta *= 0.5 / m;
            ab += delta;
        }
        if (!done) return false;
        if (!(ab.x >= 0.0 && ab.y >= 0.0 && ab.x + ab.y <= 1.0)) return false;
        for (uint v = 1u; v < k; v++) {
            LOOP_EDGE(W_CHAIN_FACETS);
            if (!point_in_triangle(mnee_cells[c + 1u + v], ch_p[v])) return false;
        }
        // The last leg must end in the scattering point's object.
        if ((ch_inside & (1u << k)) == 0u || ch_mat[k] != path_mat) return false;
    }
    if (!(E > 0.0) || isinf(E)) return false;
    if (check) {
        // Legs in vacuum: the light's (leg 0, from a light outside) and any between objects or
        // sheets. Legs inside are tracked, and a surface across one blocks it (tracking.glsl).
        if (light_in) {
        } else if (point) {
            if (!leg_clear(light, ch_p[0])) return false;
        } else {
            float t;
            uint tri;
            if (mesh_hit_tri(ch_p[0], -light, surface_eps(ch_p[0]), INF, t, tri)) return false;
        }
        for (uint l = 1u; l < k; l++) {
            LOOP_EDGE(W_CHAIN_LEGS);
            if ((ch_inside & (1u << l)) == 0u && !leg_clear(ch_p[l - 1u], ch_p[l])) return false;
        }
    }
    return true;
}

// Manifold next-event estimation from the scattering point p (the free flight's ray d) toward
// light li (point or directional, outside every object) through the objects' surfaces: every
// chain of p's cell that holds at p (chain_at) adds the transmittance of its legs inside
// objects, by ratio tracking in each leg's material, times the irradiance it delivers:
//   single refraction, point: E = I (1 - F) / [(l_o + l_i / eta) (l_o cos_i / cos_o + (l_i / eta) cos_o / cos_i)],
//   single refraction, directional: E (1 - F) cos_o / cos_i,
// with l_o, cos_o outside (vacuum) and l_i, cos_i inside (src/physics/dielectric.rs); longer
// chains: the ray tube's spreading, traced (chain_at).
// Physical irradiance: the camera path's throughput carries its own 1 / eta^2.
// Only the chains of p's cell in the light's grid are tried (mnee_range). Resumable: ev_sub 2
// scans the cell's list from position ev_surf_tri on; 3 + l tracks leg l (from k down to 1) of
// the chain at ev_surf_tri, solved again on resume (the same vertices), with the legs' product
// so far in ev_v. Returns false when it paused.
bool mnee_estimate(Light li, vec3 p, vec3 d, float g, vec3 beta, inout vec3 L, inout uvec2 rng) {
    bool point = uint(li.pos_kind.w) == LIGHT_POINT;
    bool check = (mnee_cells[7] & 1u) != 0u;
    bool light_in = mnee_light_inside(ev_light);
    uint begin, end;
    mnee_range(ev_light, p, begin, end);
    if (ev_sub == 0u) {
        ev_surf_tri = begin;
        ev_sub = 2u;
    }
    float E = 0.0;
    while (true) {
        BATCH_EDGE(W_MNEE_CHAINS);
        if (ev_sub == 2u) {
            bool found = false;
            for (; ev_surf_tri < end; ev_surf_tri++) {
                BATCH_EDGE(W_MNEE_TRY);
                if (SPENT(iter_limit)) return false;
                iters += CHAIN_TRY_ITERS;
                if (chain_at(mnee_cells[ev_surf_tri], p, li.pos_kind.xyz, point, light_in, check, E)) {
                    found = true;
                    break;
                }
            }
            if (!found) return true;
            ev_v = vec3(1.0);
            ev_sub = 3u + (mnee_cells[mnee_cells[ev_surf_tri]] & 0xffu);
        } else {
            // Resuming a paused leg: the same chain gives the same vertices and irradiance (its
            // vacuum legs were found clear before).
            chain_at(mnee_cells[ev_surf_tri], p, li.pos_kind.xyz, point, light_in, false, E);
        }
        uint k = mnee_cells[mnee_cells[ev_surf_tri]] & 0xffu;
        // Legs k down to 0 (leg 0 lies inside only from a light inside an object).
        for (; ev_sub >= 3u; ev_sub--) {
            LOOP_EDGE(W_MNEE_LEGS);
            uint l = ev_sub - 3u;
            if ((ch_inside & (1u << l)) != 0u) {
                // Tracked from the leg's far end (x, or just inside vertex l) back to vertex
                // l - 1 (or the light).
                vec3 a = l == 0u ? li.pos_kind.xyz : ch_p[l - 1u];
                vec3 b = l == k ? p : ch_p[l];
                vec3 to = a - b;
                float len = length(to);
                if (len > 0.0) {
                    vec3 wi = to / len;
                    float e = l == k ? 0.0 : surface_eps(b);
                    float ea = l == 0u ? 0.0 : e;
                    uint saved = path_mat;
                    path_mat = ch_mat[l];
                    track_start(b + wi * e, wi, len * (1.0 - 1e-4) - e - ea, true);
                    bool ok = transmittance_run(rng);
                    path_mat = saved;
                    if (!ok) return false;
                    ev_v *= trk.T;
                    if (max3(ev_v) <= 0.0) break;
                }
            }
            if (l == 0u) break;
        }
        if (max3(ev_v) > 0.0 && E > 0.0) {
            vec3 wi = normalize(ch_p[k - 1u] - p);
            L += beta * ev_v * phase_eval(g, dot(d, wi)) * li.value.rgb * E;
        }
        ev_surf_tri++;
        ev_sub = 2u;
    }
    return true;
}
#endif
