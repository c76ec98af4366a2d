/* gscodec.h — C interface of the gscodec decoder (Rust crate `gscodec-decoder`, feature `capi`).
 *
 * Link against the static library built by
 *     cargo build --release -p gscodec-decoder --features capi
 * (target/release/libgscodec_decoder.a; on Linux also link -lpthread -ldl -lm).
 *
 * Usage:
 *     GscScene *scene = NULL;
 *     if (gsc_decode(bytes, len, 3, 0, &scene) != GSC_OK) {
 *         fprintf(stderr, "decode failed: %s\n", gsc_last_error());
 *     } else {
 *         size_t n = gsc_scene_count(scene);
 *         const float *xyz = gsc_scene_positions(scene);   // n * 3 floats
 *         ...
 *         gsc_scene_free(scene);
 *     }
 *
 * No function unwinds or aborts on bad input: failures return a negative code and set a
 * thread-local message (gsc_last_error). Array pointers stay valid until gsc_scene_free.
 */
#ifndef GSCODEC_H
#define GSCODEC_H

#include <stddef.h>
#include <stdint.h>

#ifdef __cplusplus
extern "C" {
#endif

/* Result codes: one per error class of the Rust decoder (DecodeError::class), plus argument
 * and internal errors. gsc_error_class(code) names a code. */
#define GSC_OK 0
#define GSC_ERR_ARGUMENT (-1)    /* NULL pointer or argument out of range */
#define GSC_ERR_FORMAT (-2)      /* "format": bad magic, truncated, corrupt, missing section, trailing data */
#define GSC_ERR_UNSUPPORTED (-3) /* "unsupported": another major version or an unknown required section */
#define GSC_ERR_INTERNAL (-4)    /* a decoder bug (caught panic) */
#define GSC_ERR_CHECKSUM (-5)    /* "checksum": a CRC-32 does not match */
#define GSC_ERR_LIMITS (-6)      /* "limits": beyond the format's bounds or the caller's GscLimits */
#define GSC_ERR_IO (-7)          /* "io": reading the input failed */

/* A decoded scene (opaque). */
typedef struct GscScene GscScene;

/* Limits of a decode, checked before anything they bound is allocated. */
typedef struct GscLimits {
    uint32_t max_gaussians; /* most Gaussians a file may hold */
    uint64_t max_bytes;     /* byte budget: file + decoded values + scene */
    int max_sh_degree;      /* 0..3: higher SH bands are not decoded */
} GscLimits;

/* The default limits (16.7 M Gaussians, 4 GiB, SH degree 3). */
GscLimits gsc_default_limits(void);

/* Decodes `len` bytes at `data` with the default limits. `max_sh_degree` (0..3) skips higher SH
 * bands; `threads` = 0 uses all cores, 1 decodes on the calling thread (the result is identical
 * for every thread count). On success *out owns a new scene; on failure *out is NULL. */
int gsc_decode(const uint8_t *data, size_t len, int max_sh_degree, int threads, GscScene **out);

/* As gsc_decode, with *limits (NULL: the defaults). */
int gsc_decode_limited(const uint8_t *data, size_t len, const GscLimits *limits, int threads, GscScene **out);

/* The class name of a result code: "ok", "argument", "format", "checksum", "unsupported",
 * "limits", "io", "internal" or "unknown" (a static string). */
const char *gsc_error_class(int code);

/* Reads only the fixed header (no checksum of the payload). Either output may be NULL. */
int gsc_peek_header(const uint8_t *data, size_t len, uint32_t *count, int *sh_degree);

/* Releases a scene; NULL is ignored. */
void gsc_scene_free(GscScene *scene);

/* Scene contents (structure of arrays, float32, the reference 3DGS parameterisation). */
size_t gsc_scene_count(const GscScene *scene);            /* Gaussians (0 for NULL) */
int gsc_scene_sh_degree(const GscScene *scene);           /* 0..3 (-1 for NULL) */
size_t gsc_scene_sh_rest_coeffs(const GscScene *scene);   /* K = (degree+1)^2 - 1 */
const float *gsc_scene_positions(const GscScene *scene);  /* count*3: x y z */
const float *gsc_scene_log_scales(const GscScene *scene); /* count*3: ln(sigma) */
const float *gsc_scene_rotations(const GscScene *scene);  /* count*4: w x y z (unnormalised) */
const float *gsc_scene_opacity_logits(const GscScene *scene); /* count: opacity before sigmoid */
const float *gsc_scene_sh_dc(const GscScene *scene);      /* count*3: SH DC per channel */
const float *gsc_scene_sh_rest(const GscScene *scene);    /* count*K*3: [(i*K + k)*3 + c] */

/* A pinhole camera (OpenCV axes: x right, y down, z forward): p_cam = R p_world + t. */
typedef struct GscCamera {
    uint32_t width, height; /* image size in pixels */
    float fx, fy;           /* focal lengths in pixels */
    float cx, cy;           /* principal point (pixel centres at i + 0.5) */
    float rotation[9];      /* world-to-camera R, row-major */
    float translation[3];   /* world-to-camera t */
    float znear;            /* Gaussians at depth z <= znear are not drawn; <= 0: 0.05 */
} GscCamera;

#define GSC_PIXEL_RGBA_F32 0 /* 4 floats per pixel: linear RGB as rendered, alpha 1 */
#define GSC_PIXEL_RGBA_U8 1  /* 4 bytes per pixel: RGB clamped to [0,1] and rounded to 0..255, alpha 255 */
#define GSC_RENDERER_CPU 1   /* gsc_render ran the CPU renderer */
#define GSC_RENDERER_GPU 2   /* gsc_render ran the GPU (wgpu) renderer */

/* Renders `scene` from `*camera` into the caller's buffer `out` of `out_len` bytes (at least
 * width*height*16 for GSC_PIXEL_RGBA_F32, 4-byte aligned, or width*height*4 for GSC_PIXEL_RGBA_U8),
 * rows top to bottom. `background` is RGB (NULL: black); `max_sh_degree` 0..3. `use_gpu` != 0
 * renders on the GPU when the library was built with the `gpu` feature and an adapter exists,
 * else (or if the GPU render fails) on the CPU; *renderer (if not NULL) receives
 * GSC_RENDERER_GPU or GSC_RENDERER_CPU. On failure `out` is left untouched. */
int gsc_render(const GscScene *scene, const GscCamera *camera, const float *background, int max_sh_degree,
               int pixel_format, int use_gpu, void *out, size_t out_len, int *renderer);

/* Message of the last failure on this thread ("" if none); never NULL. */
const char *gsc_last_error(void);

/* Library version string, e.g. "0.1.0". */
const char *gsc_version(void);

#ifdef __cplusplus
}
#endif

#endif /* GSCODEC_H */
