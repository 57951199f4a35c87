// Shader 1 of the GL path (the paper's first shader): per aperture sample, the light's
// transport to the stop (P_o, or the analytic incoming wave) and the stop basis rows.
//
// One invocation per sample. For each light: the outer-pupil clip, the transmittance,
// and the optical path length in double, converted to waves and reduced to [-1/2, 1/2]
// in double, so that only the fraction (all the sine and cosine need) reaches float.
// For fitted lenses also the values of the window's basis functions g_j(sample) of
// every output (inner pupil x, y, transmittance, phase), rounded to float.
//
// The host prepends `#version 430` and the scene's constants (see gl_render.c):
// NL lights, NW wavelengths, NS stop monomials (slots), NB = NS - 1 basis functions,
// DEGREE, PASS (samples per buffer), MONO_RADIUS (mm), HOUSING_FIRST (mm),
// ANALYTIC with FOCAL_MM_SET and FOCAL_MM (a perfect lens; else free space), NAIVE
// (total phase kept unreduced and rounded to float, to show why the default does not),
// NCLIP_O and NCLIP_S (a ghost's P_clip pairs on side P_o or P_s; 0 for direct renders)
// and CLIP_LIMIT2_0..3; with STOP_SHAPED (a ghost's stop crossings and a bladed or slit
// stop), STOP_SHAPED_0..3 and stop_inside(x, y) (gl_render.c, stop_text).
layout(local_size_x = 64) in;

layout(std430, binding = 0) readonly buffer SampleXY { dvec2 sample_xy[]; };      // mm on the stop
layout(std430, binding = 1) readonly buffer SampleIn { float sample_inside[]; };  // 1 inside the aperture shape, else 0
layout(std430, binding = 2) readonly buffer Po { double po[]; };     // [((l NW + w) 8 + o) NS + slot]: x_o, y_o, tau_o, phi_o, flux Jacobian
layout(std430, binding = 3) readonly buffer Basis { double basis[]; }; // [(w 4 + o) NB NB + (slot - 1) NB + j]
layout(std430, binding = 4) readonly buffer Lights { dvec4 lights[]; }; // (sqrt intensity, distance mm, dir x, dir y)
layout(std430, binding = 5) readonly buffer Lambda { double lambda_mm[]; };
layout(std430, binding = 6) writeonly buffer Rows { float rows[]; };  // [(o NB + j) PASS + s]
layout(std430, binding = 7) writeonly buffer LightSample { vec2 light_sample[]; }; // [l PASS + s]: (phase waves, amplitude)

uniform uint u_w;  // wavelength index
uniform uint u_n;  // samples in the buffer (the rest is padding with amplitude 0)
uniform ivec4 u_rows; // basis rows to compute per output (x, y, tau, phase), 0..NB

void main()
{
    uint s = gl_GlobalInvocationID.x;
    if (s >= uint(PASS)) return;
    dvec2 xy = sample_xy[s];
    double inside = s < u_n ? double(sample_inside[s]) : 0.0LF;
    double lambda = lambda_mm[u_w];
#if ANALYTIC
    // Incoming wave at the stop: plane or spherical from the light; a perfect lens turns
    // it into a sphere converging on the light's image
    for (int l = 0; l < NL; l++) {
        dvec4 L = lights[l];
        double amp = inside * L.x, D = L.y, lx = L.z, ly = L.w, lz = sqrt(1.0LF - lx * lx - ly * ly);
        double opl, offset;
#if FOCAL_MM_SET
        double f = FOCAL_MM;
        double v = D > 0.0LF ? 1.0LF / (1.0LF / f - 1.0LF / (D * lz)) : f;
        double ix = D > 0.0LF ? -(v / (D * lz)) * D * lx : -v * lx / lz;
        double iy = D > 0.0LF ? -(v / (D * lz)) * D * ly : -v * ly / lz;
        opl = -sqrt((ix - xy.x) * (ix - xy.x) + (iy - xy.y) * (iy - xy.y) + v * v);
        offset = D > 0.0LF ? D + v : v;   // what the naive mode keeps
#else
        if (D > 0.0LF) {
            opl = sqrt((D * lx - xy.x) * (D * lx - xy.x) + (D * ly - xy.y) * (D * ly - xy.y) + D * lz * D * lz) - D;
            offset = D;
        } else {
            opl = -(lx * xy.x + ly * xy.y);
            offset = 0.0LF;
        }
#endif
        double waves = (NAIVE != 0 ? opl + offset : opl) / lambda;
        // Reduce in double: only the fraction of a wave matters
        if (NAIVE == 0) waves -= roundEven(waves);
        light_sample[uint(l) * uint(PASS) + s] = vec2(float(waves), float(amp));
    }
#else
    // Stop monomials u^m v^n (u = x / R, v = y / R), ordered by degree then by n
    double mono[NS];
    {
        double u = xy.x / MONO_RADIUS, v = xy.y / MONO_RADIUS, pu[DEGREE + 1], pv[DEGREE + 1];
        pu[0] = 1.0LF;
        pv[0] = 1.0LF;
        for (int k = 1; k <= DEGREE; k++) {
            pu[k] = pu[k - 1] * u;
            pv[k] = pv[k - 1] * v;
        }
        int slot = 0;
        for (int d = 0; d <= DEGREE; d++)
            for (int n = 0; n <= d; n++) mono[slot++] = pu[d - n] * pv[n];
    }
    // P_o per light: outer-pupil clip, transmittance, OPL from the light minus its distance
    for (int l = 0; l < NL; l++) {
        uint at = (uint(l) * uint(NW) + u_w) * 8u * uint(NS);
        double xo = 0.0LF, yo = 0.0LF, tau = 0.0LF, opl = 0.0LF;
        dvec4 jac = dvec4(0.0LF);
        for (int k = 0; k < NS; k++) {
            xo += po[at + uint(k)] * mono[k];
            yo += po[at + uint(NS + k)] * mono[k];
            tau += po[at + uint(2 * NS + k)] * mono[k];
            opl += po[at + uint(3 * NS + k)] * mono[k];
            jac += dvec4(po[at + uint(4 * NS + k)], po[at + uint(5 * NS + k)], po[at + uint(6 * NS + k)],
                         po[at + uint(7 * NS + k)]) * mono[k];
        }
        // The front group's flux per unit stop area (core/specialise.h, lensrt_front_flux)
        double flux = abs(jac.x * jac.w - jac.y * jac.z);
        if (lights[l].y > 0.0LF) {
            double D = lights[l].y, lx = lights[l].z, ly = lights[l].w, lz = -sqrt(1.0LF - lx * lx - ly * ly);
            dvec3 v = dvec3(xo - D * lx, yo - D * ly, -D * lz);
            flux /= abs(dot(dvec3(lx, ly, lz), v) / sqrt(dot(v, v)));
        }
        tau *= min(flux, 100.0LF); // LENSRT_MAX_FLUX
        double amp = inside * lights[l].x;
        if (xo * xo + yo * yo > HOUSING_FIRST * HOUSING_FIRST) amp = 0.0LF;
#if NCLIP_O > 0
        // A ghost's P_clip on this side (after P_o in the buffer): every pair must pass
        for (int q = 0; q < NCLIP_O; q++) {
            uint cat = uint(NL * NW * 8 * NS) + ((uint(l) * uint(NW) + u_w) * uint(2 * NCLIP_O) + uint(2 * q)) * uint(NS);
            double hx = 0.0LF, hy = 0.0LF;
            for (int k = 0; k < NS; k++) {
                hx += po[cat + uint(k)] * mono[k];
                hy += po[cat + uint(NS + k)] * mono[k];
            }
            double lim2 = q == 0 ? CLIP_LIMIT2_0 : q == 1 ? CLIP_LIMIT2_1 : q == 2 ? CLIP_LIMIT2_2 : CLIP_LIMIT2_3;
            if (hx * hx + hy * hy > lim2) amp = 0.0LF;
#ifdef STOP_SHAPED
            // A stop crossing of a bladed or slit stop: inside its shape too
            int shaped = q == 0 ? STOP_SHAPED_0 : q == 1 ? STOP_SHAPED_1 : q == 2 ? STOP_SHAPED_2 : STOP_SHAPED_3;
            if (shaped != 0 && !stop_inside(hx, hy)) amp = 0.0LF;
#endif
        }
#endif
        amp *= sqrt(max(tau, 0.0LF));
        if (NAIVE != 0) opl += lights[l].y;
        double waves = opl / lambda;
        if (NAIVE == 0) waves -= roundEven(waves);
        light_sample[uint(l) * uint(PASS) + s] = vec2(float(waves), float(amp));
    }
    // The window's basis functions at this sample, per output (double, then float)
    for (int o = 0; o < 4; o++) {
        uint at = (u_w * 4u + uint(o)) * uint(NB * NB);
        for (int j = 0; j < u_rows[o]; j++) {
            double g = 0.0LF;
            for (int k = 1; k < NS; k++) g += basis[at + uint((k - 1) * NB + j)] * mono[k];
            rows[uint(o * NB + j) * uint(PASS) + s] = float(g);
        }
    }
#if NCLIP_S > 0
    // A ghost's P_clip on side P_s: the stop monomials themselves, after the basis rows
    for (int k = 0; k < NS; k++) rows[uint(4 * NB + k) * uint(PASS) + s] = float(mono[k]);
#endif
#endif
}
