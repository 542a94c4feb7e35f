/* The functions of Python's math module that CPython computes itself rather than through the C library, ported
 * operation for operation so that the traced models' C gives CPython's bits (docs/traced-c.md). Included by every
 * generated file; compiled with -ffp-contract=off.
 *
 * The algorithms are CPython's (Modules/mathmodule.c, Python Software Foundation License): math.fsum is msum
 * (Shewchuk's exact partials, with CPython's handling of infinities and its half-even correction), math.remainder
 * is m_remainder, math.hypot of two coordinates is vector_norm as in CPython 3.11 (Veltkamp-Dekker splitting,
 * compensated sums, a differential correction of the square root; 3.12 computes the squares with an fma instead).
 */
#ifndef DSC_TRACED_MATH_H
#define DSC_TRACED_MATH_H

#include <float.h>
#include <math.h>

#ifdef _WIN32
/* CPython on Windows takes the C library's math from the Universal C Runtime, and MinGW-w64 (Zig's windows-gnu)
 * would link its own sin, cos and fmod into the DLL: declared imported, they are the UCRT's, as CPython's are. */
#pragma clang diagnostic push
#pragma clang diagnostic ignored "-Wdll-attribute-on-redeclaration"
__declspec(dllimport) double __cdecl sin(double);
__declspec(dllimport) double __cdecl cos(double);
__declspec(dllimport) double __cdecl atan(double);
__declspec(dllimport) double __cdecl fmod(double, double);
#pragma clang diagnostic pop
#endif

/* math.fsum of values[0..n-1]; *raised: whether Python raises (an intermediate overflow, -inf + inf). */
static inline double dsc_fsum(int n, const double *values, int *raised)
{
    double partials[64];
    double x, y, t, hi, yr, lo = 0.0, xsave, special_sum = 0.0, inf_sum = 0.0;
    int i, j, count = 0, k;

    *raised = 0;
    for (k = 0; k < n; k++) {
        x = values[k];
        xsave = x;
        for (i = j = 0; j < count; j++) {
            y = partials[j];
            if (fabs(x) < fabs(y)) {
                t = x;
                x = y;
                y = t;
            }
            hi = x + y;
            yr = hi - x;
            lo = y - yr;
            if (lo != 0.0)
                partials[i++] = lo;
            x = hi;
        }
        count = i;
        if (x != 0.0) {
            if (!isfinite(x)) {
                if (isfinite(xsave)) {
                    *raised = 1;
                    return NAN;
                }
                if (isinf(xsave))
                    inf_sum += xsave;
                special_sum += xsave;
                count = 0;
            } else {
                partials[count++] = x;
            }
        }
    }
    if (special_sum != 0.0) {
        *raised = isnan(inf_sum);
        return special_sum;
    }
    hi = 0.0;
    if (count > 0) {
        hi = partials[--count];
        while (count > 0) {
            x = hi;
            y = partials[--count];
            hi = x + y;
            yr = hi - x;
            lo = y - yr;
            if (lo != 0.0)
                break;
        }
        if (count > 0 && ((lo < 0.0 && partials[count - 1] < 0.0) || (lo > 0.0 && partials[count - 1] > 0.0))) {
            y = lo * 2.0;
            x = hi + y;
            yr = x - hi;
            if (y == yr)
                hi = x;
        }
    }
    return hi;
}

/* math.remainder(x, y): x less the nearest multiple of y, ties to the even multiple. */
static inline double dsc_remainder(double x, double y)
{
    if (isfinite(x) && isfinite(y)) {
        double absx, absy, c, m, r;
        if (y == 0.0)
            return NAN;
        absx = fabs(x);
        absy = fabs(y);
        m = fmod(absx, absy);
        c = absy - m;
        if (m < c)
            r = m;
        else if (m > c)
            r = -c;
        else
            r = m - 2.0 * fmod(0.5 * (absx - m), absy);
        return copysign(1.0, x) * r;
    }
    if (isnan(x))
        return x;
    if (isnan(y))
        return y;
    if (isinf(x))
        return NAN;
    return x;
}

/* The length of the vector of the n >= 2 magnitudes vec (modified), max the largest: CPython 3.11's vector_norm. */
static inline double dsc_vector_norm(int n, double *vec, double max)
{
    const double T27 = 134217729.0; /* ldexp(1.0, 27) + 1.0 */
    double x, scale, oldcsum, csum = 1.0, frac1 = 0.0, frac2 = 0.0, frac3 = 0.0, t, hi, lo, h;
    int max_e, i;

    frexp(max, &max_e);
    if (max_e >= -1023) {
        scale = ldexp(1.0, -max_e);
        for (i = 0; i < n; i++) {
            x = vec[i];
            x *= scale;
            t = x * T27;
            hi = t - (t - x);
            lo = x - hi;
            x = hi * hi;
            oldcsum = csum;
            csum += x;
            frac1 += (oldcsum - csum) + x;
            x = 2.0 * hi * lo;
            oldcsum = csum;
            csum += x;
            frac2 += (oldcsum - csum) + x;
            frac3 += lo * lo;
        }
        h = sqrt(csum - 1.0 + (frac1 + frac2 + frac3));
        x = h;
        t = x * T27;
        hi = t - (t - x);
        lo = x - hi;
        x = -hi * hi;
        oldcsum = csum;
        csum += x;
        frac1 += (oldcsum - csum) + x;
        x = -2.0 * hi * lo;
        oldcsum = csum;
        csum += x;
        frac2 += (oldcsum - csum) + x;
        x = -lo * lo;
        oldcsum = csum;
        csum += x;
        frac3 += (oldcsum - csum) + x;
        x = csum - 1.0 + (frac1 + frac2 + frac3);
        return (h + x / (2.0 * h)) / scale;
    }
    for (i = 0; i < n; i++) {
        x = vec[i];
        x /= max;
        x = x * x;
        oldcsum = csum;
        csum += x;
        frac1 += (oldcsum - csum) + x;
    }
    return max * sqrt(csum - 1.0 + frac1);
}

/* math.hypot(x, y). */
static inline double dsc_hypot(double x, double y)
{
    double vec[2] = {fabs(x), fabs(y)};
    double max = vec[0] > vec[1] ? vec[0] : vec[1];
    if (isinf(vec[0]) || isinf(vec[1]))
        return INFINITY;
    if (isnan(vec[0]) || isnan(vec[1]))
        return NAN;
    if (max == 0.0)
        return max;
    return dsc_vector_norm(2, vec, max);
}

#endif
