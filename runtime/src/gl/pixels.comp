// Pixel set-up of the GL path (fitted lenses): P_s specialised to each pixel, in double.
//
// One invocation per pixel, once per wavelength and pass (it depends on neither the
// samples nor the pass, but recomputing it costs far less than storing it). As on the
// CPU (render.c, setup_pixel): the coefficients c_k of the stop monomials at the pixel,
// bounds that decide whether every path through the pixel is clipped (dark) or none is
// (no clip test), the phase in waves with its constant dropped, and the Huygens
// amplitude sqrt|det d2 phi / (d a d s)| / lambda by central differences. Each output's
// coefficients are then written in the window's orthonormal basis V (u = V^T c), and
// the fewest leading basis vectors whose dropped tail has an l1 norm under the output's
// tolerance (a rigorous bound: every monomial is at most 1 on the sampled region) is
// folded into ranks[] with atomicMax: the splat shader uses that many per output.
//
// The host prepends the scene's constants: NS, NB, W (pixels per row), SENSOR_CX,
// SENSOR_SX, SENSOR_CY, SENSOR_SY (normalisation of x_S, y_S), HOUSING_LAST (mm),
// LIMIT_PUPIL (mm), LIMIT_TAU_REL, TOL_PHASE (waves): the l1 norm each output may drop
// (render.c, lensrt_output_limit), STEP_MM, MONO_RADIUS (mm), NAIVE, NCLIP_S and
// CLIP_LIMIT2_0..3 (a ghost's P_clip pairs on side P_s; 0 for direct renders); with
// STOP_SHAPED (stop crossings and a bladed or slit stop), STOP_SHAPED_0..3 and
// stop_box(cx, bx, cy, by) (gl_render.c, stop_text).
layout(local_size_x = 64) in;

layout(std430, binding = 3) readonly buffer Basis { double basis[]; };  // [(w 4 + o) NB NB + (slot - 1) NB + j]
layout(std430, binding = 5) readonly buffer Lambda { double lambda_mm[]; };
layout(std430, binding = 8) readonly buffer PixX { double pix_x[]; };   // pixel centres (mm)
layout(std430, binding = 9) readonly buffer PixY { double pix_y[]; };
layout(std430, binding = 10) readonly buffer PsCoef { double ps_coef[]; };
layout(std430, binding = 11) readonly buffer PsCode { uint ps_code[]; }; // ix | iy << 8 | slot << 16
layout(std430, binding = 12) readonly buffer PsOff { uint ps_off[]; };   // terms of (w, o): [w 4 + o, w 4 + o + 1)
layout(std430, binding = 13) writeonly buffer Records { float records[]; };
layout(std430, binding = 17) readonly buffer Norm1 { double norm1[]; }; // [(w 4 + o) NB + j]: |V_j|_1
layout(std430, binding = 14) buffer Ranks { uint ranks[]; };  // [w 4 + o] max keep; then [NW 4 + 0..2]: dark, clip, tau counts

uniform uint u_w, u_first, u_count, u_stride;
uniform ivec4 u_k;  // coefficients written per output (the ranks found so far)
uniform uint u_nw;

// Coefficients of the stop monomials of entry e of the term list (e = w 4 + o for P_s,
// NW 4 + w 2 NCLIP_S + o for a ghost's P_clip on side P_s) at normalised sensor point
// (xh, yh)
void entry_coefficients(uint e, double xh, double yh, inout double c[NS])
{
    double px[16], py[16];
    px[0] = 1.0LF;
    py[0] = 1.0LF;
    for (int e = 1; e < 16; e++) {
        px[e] = px[e - 1] * xh;
        py[e] = py[e - 1] * yh;
    }
    for (int k = 0; k < NS; k++) c[k] = 0.0LF;
    for (uint t = ps_off[e]; t < ps_off[e + 1u]; t++) {
        uint code = ps_code[t];
        c[code >> 16] += ps_coef[t] * px[code & 255u] * py[(code >> 8) & 255u];
    }
}

// Coefficients of the stop monomials of output o at normalised sensor point (xh, yh)
void slot_coefficients(uint o, double xh, double yh, inout double c[NS])
{
    entry_coefficients(u_w * 4u + o, xh, yh, c);
}

// d phi / d u and d phi / d v at the stop centre (slots 1 and 2), phi in mm
dvec2 phase_gradient(double xh, double yh)
{
    double px[16], py[16];
    px[0] = 1.0LF;
    py[0] = 1.0LF;
    for (int e = 1; e < 16; e++) {
        px[e] = px[e - 1] * xh;
        py[e] = py[e - 1] * yh;
    }
    dvec2 g = dvec2(0.0LF);
    for (uint t = ps_off[u_w * 4u + 3u]; t < ps_off[u_w * 4u + 4u]; t++) {
        uint code = ps_code[t], slot = code >> 16;
        double v = ps_coef[t] * px[code & 255u] * py[(code >> 8) & 255u];
        if (slot == 1u) g.x += v;
        if (slot == 2u) g.y += v;
    }
    return g;
}

void main()
{
    uint q = gl_GlobalInvocationID.x;
    if (q >= u_count) return;
    uint p = u_first + q, at = q * u_stride;
    double x = pix_x[p % uint(W)], y = pix_y[p / uint(W)];
    double xh = (x - SENSOR_CX) / SENSOR_SX, yh = (y - SENSOR_CY) / SENSOR_SY;
    double lambda = lambda_mm[u_w], h = HOUSING_LAST;
    // Constant terms and bounds of the varying parts, per output
    double c0[4], bound[4], co[NS];
    for (int o = 0; o < 4; o++) {
        slot_coefficients(uint(o), xh, yh, co);
        c0[o] = co[0];
        bound[o] = 0.0LF;
        for (int k = 1; k < NS; k++) bound[o] += abs(co[k]);
    }
    for (uint i = 0u; i < u_stride; i++) records[at + i] = 0.0;
    // Inner pupil: skip the clip when every path passes, the pixel when none does
    double hi = length(dvec2(abs(c0[0]) + bound[0], abs(c0[1]) + bound[1]));
    double lo_x = abs(c0[0]) - bound[0], lo_y = abs(c0[1]) - bound[1];
    if (lo_x > h || lo_y > h || (lo_x > 0.0LF && lo_y > 0.0LF && length(dvec2(lo_x, lo_y)) > h)) {
        atomicAdd(ranks[u_nw * 4u], 1u);
        return;  // amplitude 0: dark
    }
    bool clip = hi > h;
#if NCLIP_S > 0
    // A ghost's P_clip pairs, decided from bounds as the inner pupil is: a pair that
    // always passes is not tested (flag 0), one that never does darkens the pixel, the
    // others are tested per splat with their full coefficients (after the basis ones)
    {
        uint cat = at + 6u + uint(u_k[0] + u_k[1] + u_k[2] + u_k[3]);
        for (int q = 0; q < NCLIP_S; q++) {
            double lim = sqrt(q == 0 ? CLIP_LIMIT2_0 : q == 1 ? CLIP_LIMIT2_1 : q == 2 ? CLIP_LIMIT2_2 : CLIP_LIMIT2_3);
            double cx[NS], cy[NS], bx = 0.0LF, by = 0.0LF;
            entry_coefficients(u_nw * 4u + u_w * uint(2 * NCLIP_S) + uint(2 * q), xh, yh, cx);
            entry_coefficients(u_nw * 4u + u_w * uint(2 * NCLIP_S) + uint(2 * q + 1), xh, yh, cy);
            for (int k = 1; k < NS; k++) {
                bx += abs(cx[k]);
                by += abs(cy[k]);
            }
            // decide: 0 none passes, 1 every one does, 2 tested per splat
            int decide;
            double cl_x = abs(cx[0]) - bx, cl_y = abs(cy[0]) - by;
            if (cl_x > lim || cl_y > lim || (cl_x > 0.0LF && cl_y > 0.0LF && length(dvec2(cl_x, cl_y)) > lim)) decide = 0;
            else decide = length(dvec2(abs(cx[0]) + bx, abs(cy[0]) + by)) <= lim ? 1 : 2;
#ifdef STOP_SHAPED
            // A stop crossing of a bladed or slit stop: the box of its possible points
            // against the shape (gl_render.c, stop_text)
            int shaped = q == 0 ? STOP_SHAPED_0 : q == 1 ? STOP_SHAPED_1 : q == 2 ? STOP_SHAPED_2 : STOP_SHAPED_3;
            if (shaped != 0) decide = stop_box(cx[0], bx, cy[0], by);
#endif
            if (decide == 0) {
                atomicAdd(ranks[u_nw * 4u], 1u);
                return;  // amplitude 0: dark
            }
            uint qat = cat + uint(q * (1 + 2 * NS));
            if (decide == 1) continue;  // flag 0: always passes
            records[qat] = 1.0;
            for (int k = 0; k < NS; k++) {
                records[qat + 1u + uint(k)] = float(cx[k]);
                records[qat + 1u + uint(NS + k)] = float(cy[k]);
            }
        }
    }
#endif
    // Each output in the window's basis, and the leading vectors it needs (the phase
    // in waves; its constant part is kept only by the naive mode)
    double limit[4] = double[4](LIMIT_PUPIL, LIMIT_PUPIL, LIMIT_TAU_REL * abs(c0[2]), TOL_PHASE);
    uint off = 6u;
    for (int o = 0; o < 4; o++) {
        if (o < 2 && !clip) {
            off += uint(u_k[o]);
            continue;
        }
        uint vat = (u_w * 4u + uint(o)) * uint(NB * NB);
        double scale = o == 3 ? 1.0LF / lambda : 1.0LF;
        slot_coefficients(uint(o), xh, yh, co);
        // Coordinates u_j = V_j . c, and the fewest leading vectors whose dropped tail
        // sum_{j >= keep} |u_j| |V_j|_1 (a bound on the residual's l1 norm) is under
        // the limit
        double u[NB];
        for (int j = 0; j < NB; j++) {
            double uj = 0.0LF;
            for (int k = 0; k < NB; k++) uj += basis[vat + uint(k * NB + j)] * co[k + 1];
            u[j] = uj * scale;
        }
        int keep = 0;
        double tail = 0.0LF;
        for (int j = NB - 1; j >= 0; j--) {
            tail += abs(u[j]) * norm1[(u_w * 4u + uint(o)) * uint(NB) + uint(j)];
            if (tail > limit[o]) {
                keep = j + 1;
                break;
            }
        }
        atomicMax(ranks[u_w * 4u + uint(o)], uint(keep));
        // The splat shader uses u_k[o] coefficients: more than keep is only better
        for (int j = 0; j < u_k[o]; j++) records[at + off + uint(j)] = float(u[j]);
        off += uint(u_k[o]);
    }
    if (clip) atomicAdd(ranks[u_nw * 4u + 1u], 1u);
    if (bound[2] > limit[2]) atomicAdd(ranks[u_nw * 4u + 2u], 1u);
    // Huygens amplitude: sqrt|det d2 phi / (d a d s)| / lambda at the stop centre
    double step = STEP_MM;
    dvec2 gx1 = phase_gradient((x + step - SENSOR_CX) / SENSOR_SX, yh);
    dvec2 gx0 = phase_gradient((x - step - SENSOR_CX) / SENSOR_SX, yh);
    dvec2 gy1 = phase_gradient(xh, (y + step - SENSOR_CY) / SENSOR_SY);
    dvec2 gy0 = phase_gradient(xh, (y - step - SENSOR_CY) / SENSOR_SY);
    double sc = 1.0LF / (2.0LF * step * MONO_RADIUS);
    double det = abs((gx1.x - gx0.x) * sc * (gy1.y - gy0.y) * sc - (gy1.x - gy0.x) * sc * (gx1.y - gx0.y) * sc);
    double amp = sqrt(det) / lambda;
    if (u_k[2] == 0) amp *= sqrt(max(c0[2], 0.0LF));  // constant transmittance
    records[at + 0u] = float(amp);
    records[at + 1u] = clip ? 1.0 : 0.0;
    records[at + 2u] = float(c0[0]);
    records[at + 3u] = float(c0[1]);
    records[at + 4u] = float(c0[2]);
    records[at + 5u] = NAIVE != 0 ? float(c0[3] / lambda) : 0.0;
}
