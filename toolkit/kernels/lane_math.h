/* The lane kernels' vector math (toolkit/kernels/lane_math.py prints it into every kernel after
 * "#define EV_W <lanes per vector>"): vector types of EV_W doubles, branch-free sin, cos, atan, atan2,
 * exp and tanh after the Cephes library's algorithms (S. L. Moshier, Methods and Programs for
 * Mathematical Functions, 1989; the coefficients of netlib's cephes/double), and the helpers the
 * kernels' expressions use. */
#ifndef EV_W
#error "define EV_W, the lanes per vector, before this text"
#endif
#include <math.h>
#include <stdint.h>
#include <string.h>
typedef double vd __attribute__((vector_size(EV_W * 8)));
typedef long long vl __attribute__((vector_size(EV_W * 8)));
#define EV_SIGN ((long long)0x8000000000000000ULL)
#define EV_ABS ((long long)0x7fffffffffffffffLL)

#define EV_INLINE static inline __attribute__((always_inline))
static inline vd ev_splat(double x) { vd r; for (int l = 0; l < EV_W; l++) r[l] = x; return r; }
static inline vd ev_and(vl m, vd a) { return (vd)(m & (vl)a); }
static inline vd ev_sel(vl m, vd a, vd b) { return (vd)((m & (vl)a) | (~m & (vl)b)); }
static inline vd ev_bool(vl m) { return ev_and(m, ev_splat(1.0)); }
static inline vd ev_fabs(vd a) { return (vd)((vl)a & EV_ABS); }
static inline vd ev_fmin(vd a, vd b) { return ev_sel((a < b) | (b != b), a, b); }
static inline vd ev_fmax(vd a, vd b) { return ev_sel((a > b) | (b != b), a, b); }
#define EV_LANES1(f, a) ({ vd _a = (a), _r; for (int _l = 0; _l < EV_W; _l++) _r[_l] = f(_a[_l]); _r; })
#define EV_LANES2(f, a, b) ({ vd _a = (a), _b = (b), _r; \
    for (int _l = 0; _l < EV_W; _l++) _r[_l] = f(_a[_l], _b[_l]); _r; })
static inline double ev_sign1(double x) { return x < 0 ? -1.0 : (x > 0 ? 1.0 : x); }
static inline vd ev_sqrt(vd a) { return EV_LANES1(sqrt, a); }
static inline vd ev_floor(vd a) {  /* exact; |a| >= 2^52 is integral already */
    vd t = __builtin_convertvector(__builtin_convertvector(a, vl), vd);
    t = t - ev_and(t > a, ev_splat(1.0));
    t = (vd)((vl)t | ((vl)a & EV_SIGN));
    return ev_sel(ev_fabs(a) < 4503599627370496.0, t, a);
}
static inline int ev_all(vl m) { long long a = -1; for (int l = 0; l < EV_W; l++) a &= m[l]; return a != 0; }
/* the lanes a vector path cannot take, through libm (out of line: rare) */
static __attribute__((noinline, cold)) vd ev_libm1(double (*f)(double), vd x, vd r, vl ok) {
    for (int l = 0; l < EV_W; l++)
        if (!ok[l]) r[l] = f(x[l]);
    return r;
}

/* Cephes atan: |x| reduced to [0, 0.66] by pi/2 - atan(1/x) above tan(3 pi/8) and
   pi/4 + atan((x-1)/(x+1)) above 0.66; x + x z P(z)/Q(z) with z = x^2. Out of line: as fast
   as inlined in the loop's kernel (measured), and the kernel compiles a fifth faster. */
static __attribute__((noinline)) vd ev_atan(vd x) {
    vl sgn = (vl)x & EV_SIGN;
    vd a = ev_fabs(x);
    vl big = a > 2.41421356237309504880;
    vl mid = (a > 0.66) & ~big;
    vd one = ev_splat(1.0);
    vd xr = ev_sel(big, -one, ev_sel(mid, a - 1.0, a)) / ev_sel(big, a, ev_sel(mid, a + 1.0, one));
    vd y0 = ev_sel(big, ev_splat(1.57079632679489661923), ev_and(mid, ev_splat(7.85398163397448309616E-1)));
    vd more = ev_sel(big, ev_splat(6.123233995736765886130E-17), ev_and(mid, ev_splat(0.5 * 6.123233995736765886130E-17)));
    vd z = xr * xr;
    vd p = (((-8.750608600031904122785E-1 * z - 1.615753718733365076637E1) * z - 7.500855792314704667340E1) * z
            - 1.228866684490136173410E2) * z - 6.485021904942025371773E1;
    vd q = ((((z + 2.485846490142306297962E1) * z + 1.650270098316988542046E2) * z + 4.328810604912902668951E2) * z
            + 4.853903996359136964868E2) * z + 1.945506571482613964425E2;
    z = z * p / q;
    z = xr * z + xr;
    z = ev_sel(big | mid, z + more, z);
    vd y = y0 + z;
    return (vd)((vl)y ^ sgn);
}

/* Cephes sin/cos: j = floor(|x| 4/pi) made even, z = |x| - j pi/4 in three parts
   (exact for |x| < 2^30), then the sine and cosine polynomials, chosen by octant. */
EV_INLINE vd ev_sin_poly(vd z, vd zz) {
    vd p = ((((1.58962301576546568060E-10 * zz - 2.50507477628578072866E-8) * zz + 2.75573136213857245213E-6) * zz
             - 1.98412698295895385996E-4) * zz + 8.33333333332211858878E-3) * zz - 1.66666666666666307295E-1;
    return z + z * (zz * p);
}
EV_INLINE vd ev_cos_poly(vd zz) {
    vd p = ((((-1.13585365213876817300E-11 * zz + 2.08757008419747316778E-9) * zz - 2.75573141792967388112E-7) * zz
             + 2.48015872888517045348E-5) * zz - 1.38888888888730564116E-3) * zz + 4.16666666666665929218E-2;
    return 1.0 - zz * 0.5 + zz * zz * p;
}
typedef struct { vd s, c; } ev_sc;
EV_INLINE ev_sc ev_sincos2(vd x) {
    vd a = ev_fabs(x);
    vl ok = a <= 1.073741824e9;
    vl j = __builtin_convertvector(ev_and(ok, a) * 1.27323954473516268615, vl);  /* floor: a >= 0 */
    vd y = __builtin_convertvector(j, vd);
    vl odd = j & 1;
    j = j + odd;
    y = y + __builtin_convertvector(odd, vd);
    j = j & 7;
    vl flip = j > 3;
    j = j - (flip & 4);
    vl ssgn = ((vl)x & EV_SIGN) ^ (flip & EV_SIGN);
    vl csgn = (flip & EV_SIGN) ^ ((j > 1) & EV_SIGN);
    vd z = ((a - y * 7.85398125648498535156E-1) - y * 3.77489470793079817668E-8) - y * 2.69515142907905952645E-15;
    vd zz = z * z;
    vd ps = ev_sin_poly(z, zz), pc = ev_cos_poly(zz);
    vl other = (j == 1) | (j == 2);
    ev_sc r;
    r.s = (vd)((vl)ev_sel(other, pc, ps) ^ ssgn);
    r.c = (vd)((vl)ev_sel(other, ps, pc) ^ csgn);
    if (__builtin_expect(!ev_all(ok), 0)) {
        r.s = ev_libm1(sin, x, r.s, ok);
        r.c = ev_libm1(cos, x, r.c, ok);
    }
    return r;
}
EV_INLINE vd ev_sin(vd x) { return ev_sincos2(x).s; }
EV_INLINE vd ev_cos(vd x) { return ev_sincos2(x).c; }

/* Cephes exp: n = floor(x log2(e) + 1/2), r = x - n ln2 in two parts, e^r by a Pade form,
   times 2^n built in the exponent bits; libm beyond [-708, 709]. */
EV_INLINE vd ev_exp(vd x) {
    vl ok = (x > -708.0) & (x < 709.0);
    vd xs = ev_and(ok, x);
    vd px = ev_floor(1.4426950408889634073599 * xs + 0.5);
    vl n = __builtin_convertvector(px, vl);
    vd r = xs - px * 6.93145751953125E-1;
    r = r - px * 1.42860682030941723212E-6;
    vd rr = r * r;
    vd p = r * ((1.26177193074810590878E-4 * rr + 3.02994407707441961300E-2) * rr + 9.99999999999999999910E-1);
    vd q = ((3.00198505138664455042E-6 * rr + 2.52448340349684104192E-3) * rr + 2.27265548208155028766E-1) * rr
           + 2.00000000000000000009E0;
    r = p / (q - p);
    r = 1.0 + 2.0 * r;
    r = r * (vd)((n + 1023) << 52);
    if (__builtin_expect(!ev_all(ok), 0)) r = ev_libm1(exp, x, r, ok);
    return r;
}

/* Cephes tanh: x + x^3 P(x^2)/Q(x^2) below 0.625, else 1 - 2/(e^{2|x|} + 1) (which is 1
   exactly from |x| = 19.1 on, so the exponential's argument is capped at 40). */
EV_INLINE vd ev_tanh(vd x) {
    vd a = ev_fabs(x);
    if (ev_all(a >= 19.5))  /* 1 - 2/(e^{2|x|} + 1) rounds to 1 from |x| = 19.06 on */
        return (vd)((vl)ev_splat(1.0) | ((vl)x & EV_SIGN));
    vl lg = a >= 0.625;
    vd s = ev_exp(2.0 * ev_fmin(a, ev_splat(20.0)));
    vd xx = x * x;
    vd p = (-9.64399179425052238628E-1 * xx - 9.92877231001918586564E1) * xx - 1.61468768441708447952E3;
    vd q = ((xx + 1.12811678491632931402E2) * xx + 2.23548839060100448583E3) * xx + 4.84406305325125486048E3;
    vd ratio = ev_sel(lg, ev_splat(2.0), p) / ev_sel(lg, s + 1.0, q);  /* one division for both branches */
    vd large = (vd)((vl)(1.0 - ratio) | ((vl)x & EV_SIGN));
    vd small = x + x * xx * ratio;
    return ev_sel(lg, large, ev_sel(x == 0.0, x, small));
}

/* Cephes atan2: atan(y/x), plus pi or -pi (by the sign of y) for x < 0; the axes and
   signed zeros as C99's atan2 (infinite arguments through libm) */
static __attribute__((noinline, cold)) vd ev_atan2_libm(vd y, vd x, vd r, vl ok) {
    for (int l = 0; l < EV_W; l++)
        if (!ok[l]) r[l] = atan2(y[l], x[l]);
    return r;
}
EV_INLINE vd ev_atan2(vd y, vd x) {
    vd pi = ev_splat(3.14159265358979323846);
    vl ysgn = (vl)y & EV_SIGN;
    vd z = ev_atan(y / x);
    vd w = (vd)((vl)pi | ysgn);
    vl xneg = (x < 0.0) | ((x == 0.0) & (((vl)x & EV_SIGN) != 0));
    z = ev_sel(xneg, w + z, z);
    /* y = +-0: +-0 for x > +0 or x = +0, +-pi for x < -0 or x = -0 */
    z = ev_sel(y == 0.0, (vd)((vl)ev_and(xneg, w) | ysgn), z);
    /* x = +-0, y != 0: +-pi/2 */
    z = ev_sel((x == 0.0) & (y != 0.0), (vd)((vl)ev_splat(1.57079632679489661923) | ysgn), z);
    vl ok = (ev_fabs(x) <= 1.7976931348623157e308) & (ev_fabs(y) <= 1.7976931348623157e308);
    if (__builtin_expect(!ev_all(ok), 0)) z = ev_atan2_libm(y, x, z, ok);
    return z;
}
