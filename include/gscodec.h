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

/* Result codes. */
#define GSC_OK 0
#define GSC_ERR_ARGUMENT (-1)            /* NULL pointer or argument out of range */
#define GSC_ERR_INVALID_DATA (-2)        /* not a valid .gsc file (magic, truncation, checksum, ...) */
#define GSC_ERR_UNSUPPORTED_VERSION (-3) /* format version newer than this decoder */
#define GSC_ERR_INTERNAL (-4)            /* a decoder bug (caught panic) */

/* A decoded scene (opaque). */
typedef struct GscScene GscScene;

/* Decodes `len` bytes at `data`. `max_sh_degree` (0..3) skips higher SH bands; `threads` = 0 uses
 * all cores (the result is identical for every thread count). On success *out owns a new scene;
 * on failure *out is NULL. */
int gsc_decode(const uint8_t *data, size_t len, int max_sh_degree, int threads, GscScene **out);

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

/* Message of the last failure on this thread ("" if none); never NULL. */
const char *gsc_last_error(void);

/* Library version string, e.g. "0.1.0". */
const char *gsc_version(void);

#ifdef __cplusplus
}
#endif

#endif /* GSCODEC_H */
