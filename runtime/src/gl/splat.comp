// Shader 2 of the GL path (the paper's second shader): every aperture sample to every
// pixel, accumulating complex phasors per light and wavelength.
//
// One invocation per pixel; every invocation walks the same samples in the same order,
// so sample data are read uniformly (broadcast). Fitted lenses: the pixel's phase is a
// short dot product of its basis coefficients (pixels.comp) with the sample's basis rows
// (samples.comp), in float: every term is small, the constant phase is dropped and the
// light's phase is already reduced, so the float sum is reduced again in float and only
// then meets sin and cos. Analytic lenses: the sample-to-pixel distance in double,
// reduced in double (GLSL has no double sine or cosine). Sums run in float over blocks
// of BLOCK samples and in double across blocks and passes (the phasor framebuffer).
//
// The host prepends the scene's constants: NL, NW, NB, PASS, W, BLOCK, KX, KY, KT, KP
// (basis terms per output for this wavelength), HOUSING_LAST (mm), UNBIASED, NAIVE,
// ANALYTIC with ONE_D and SENSOR_Z_MM, NCLIP_S and CLIP_LIMIT2_0..3 (a ghost's P_clip
// pairs on side P_s; 0 for direct renders).
layout(local_size_x = 64) in;

layout(std430, binding = 0) readonly buffer SampleXY { dvec2 sample_xy[]; };
layout(std430, binding = 5) readonly buffer Lambda { double lambda_mm[]; };
layout(std430, binding = 6) readonly buffer Rows { float rows[]; };
layout(std430, binding = 7) readonly buffer LightSample { vec2 light_sample[]; };
layout(std430, binding = 8) readonly buffer PixX { double pix_x[]; };
layout(std430, binding = 9) readonly buffer PixY { double pix_y[]; };
layout(std430, binding = 13) readonly buffer Records { float records[]; };
layout(std430, binding = 15) buffer Sums { dvec2 sums[]; };     // [(l NW + w) npix + p]
layout(std430, binding = 16) buffer SumSq { double sumsq[]; };  // the same, with UNBIASED

uniform uint u_w, u_n, u_first, u_count, u_stride, u_npix;

const float TWO_PI = 6.28318530717958647692;

#if NCLIP_S > 0
// A ghost's P_clip pairs on side P_s at sample s, from the pixel's records at b (per
// pair: a flag, then x's and y's stop-monomial coefficients) and the stop monomials
// (rows after the basis rows): 0 when a tested pair fails (its circle, or for a stop
// crossing of a bladed or slit stop its edges or slits), else 1. CLIP_WEIGHT_BODY is
// straight-line code made by the host (gl_render.c, clip_code): no loop, since llvmpipe
// ends an invocation after 65,535 loop iterations in all.
float clip_weight(uint b, uint s)
{
    float w = 1.0, hx, hy;
    CLIP_WEIGHT_BODY
    return w;
}
#endif

void main()
{
    uint q = gl_GlobalInvocationID.x;
    if (q >= u_count) return;
    uint p = u_first + q;
#if ANALYTIC
    // Free space after the stop: Rayleigh-Sommerfeld cos(theta) / (lambda r), or
    // cos(theta) / sqrt(lambda r) for cylindrical waves
    double x = pix_x[p % uint(W)], y = pix_y[p / uint(W)], z = SENSOR_Z_MM, lambda = lambda_mm[u_w];
    double amp_px = 1.0LF;
#else
    uint at = q * u_stride;
    float amp_px = records[at];
    if (amp_px == 0.0) return;  // every path through the pixel is clipped
    bool clip = records[at + 1u] != 0.0;
    float x0 = records[at + 2u], y0 = records[at + 3u], tau0 = records[at + 4u], phase0 = records[at + 5u];
    float ux[KX + 1], uy[KY + 1], ut[KT + 1], up[KP + 1];
    for (int j = 0; j < KX; j++) ux[j] = records[at + 6u + uint(j)];
    for (int j = 0; j < KY; j++) uy[j] = records[at + 6u + uint(KX + j)];
    for (int j = 0; j < KT; j++) ut[j] = records[at + 6u + uint(KX + KY + j)];
    for (int j = 0; j < KP; j++) up[j] = records[at + 6u + uint(KX + KY + KT + j)];
#endif
    for (uint s0 = 0u; s0 < u_n; s0 += uint(BLOCK)) {
        vec2 acc[NL];
        float sq[NL];
        for (int l = 0; l < NL; l++) {
            acc[l] = vec2(0.0);
            sq[l] = 0.0;
        }
        uint s1 = min(s0 + uint(BLOCK), u_n);
        for (uint s = s0; s < s1; s++) {
#if ANALYTIC
            dvec2 a = sample_xy[s];
            double dx = x - a.x, dy = y - a.y, r2 = dx * dx + dy * dy + z * z, r = sqrt(r2);
            double path = r / lambda;
            float weight = float(ONE_D != 0 ? z / (r * sqrt(lambda * r)) : z / (lambda * r2));
#else
            // The pixel's phase (waves) and weight at this sample
            float ph = phase0;
            for (int j = 0; j < KP; j++) ph += up[j] * rows[uint(3 * NB + j) * uint(PASS) + s];
            float weight = 1.0;
#if KT > 0
            float tau = tau0;
            for (int j = 0; j < KT; j++) tau += ut[j] * rows[uint(2 * NB + j) * uint(PASS) + s];
            weight = sqrt(max(tau, 0.0));
#endif
            if (clip) {
                // Inner-pupil clip against the last housing
                float xi = x0, yi = y0;
                for (int j = 0; j < KX; j++) xi += ux[j] * rows[uint(j) * uint(PASS) + s];
                for (int j = 0; j < KY; j++) yi += uy[j] * rows[uint(NB + j) * uint(PASS) + s];
                if (xi * xi + yi * yi > float(HOUSING_LAST * HOUSING_LAST)) weight = 0.0;
            }
#if NCLIP_S > 0
            // A ghost's P_clip pairs that the pixel set-up could not decide
            weight *= clip_weight(at + 6u + uint(KX + KY + KT + KP), s);
#endif
#endif
            for (int l = 0; l < NL; l++) {
                vec2 ls = light_sample[uint(l) * uint(PASS) + s];  // (phase waves, amplitude)
#if ANALYTIC
#if NAIVE
                float t = float(path) + ls.x;
#else
                double td = path + double(ls.x);
                float t = float(td - roundEven(td));  // reduce in double
#endif
#else
                float t = ph + ls.x;
#endif
                t -= roundEven(t);
                float a = weight * ls.y;
                acc[l] += a * vec2(cos(TWO_PI * t), sin(TWO_PI * t));
                sq[l] += a * a;
            }
        }
        // Add the block to the phasor framebuffer (each pixel is one invocation: no
        // atomics needed); block by block, so that the sums do not depend on how run()
        // calls split the samples at multiples of BLOCK
        for (int l = 0; l < NL; l++) {
            uint i = (uint(l) * uint(NW) + u_w) * u_npix + p;
            sums[i] += dvec2(acc[l]) * double(amp_px);
#if UNBIASED
            sumsq[i] += double(sq[l]) * double(amp_px) * double(amp_px);
#endif
        }
    }
}
