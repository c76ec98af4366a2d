/* Decodes a .gsc file through the C ABI and dumps the scene for comparison with the Rust decoder.
 *   decode_gsc IN.gsc OUT.bin   -> OUT.bin: u32 count, i32 degree, then every array as float32
 *                                  (positions, log_scales, rotations, opacity, sh_dc, sh_rest)
 * Also checks error handling: garbage input, NULL arguments, and the header peek. Exit 0 = pass. */
#include "gscodec.h"
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#define CHECK(cond) do { if (!(cond)) { fprintf(stderr, "check failed: %s (line %d)\n", #cond, __LINE__); return 1; } } while (0)

static int dump(FILE *f, const float *p, size_t n) {
    return n == 0 || (p != NULL && fwrite(p, sizeof(float), n, f) == n);
}

int main(int argc, char **argv) {
    if (argc != 3) { fprintf(stderr, "usage: %s IN.gsc OUT.bin\n", argv[0]); return 2; }
    FILE *in = fopen(argv[1], "rb");
    CHECK(in != NULL);
    fseek(in, 0, SEEK_END);
    long len = ftell(in);
    fseek(in, 0, SEEK_SET);
    uint8_t *buf = malloc(len > 0 ? (size_t)len : 1);
    CHECK(buf != NULL && fread(buf, 1, (size_t)len, in) == (size_t)len);
    fclose(in);

    /* Error paths never crash and report a message. */
    GscScene *scene = (GscScene *)1;
    const uint8_t garbage[] = "definitely not a gsc file";
    CHECK(gsc_decode(garbage, sizeof garbage, 3, 0, &scene) == GSC_ERR_FORMAT);
    CHECK(scene == NULL);
    CHECK(strlen(gsc_last_error()) > 0);
    CHECK(strcmp(gsc_error_class(GSC_ERR_FORMAT), "format") == 0);
    CHECK(strcmp(gsc_error_class(GSC_ERR_LIMITS), "limits") == 0 && strcmp(gsc_error_class(12345), "unknown") == 0);
    /* A flipped last byte fails a section checksum; a budget of 10 bytes (less than any file) fails the limits. */
    if (len > 0) {
        buf[len - 1] ^= 1;
        CHECK(gsc_decode(buf, (size_t)len, 3, 0, &scene) == GSC_ERR_CHECKSUM && scene == NULL);
        CHECK(strstr(gsc_last_error(), "checksum") != NULL);
        buf[len - 1] ^= 1;
    }
    GscLimits tight = gsc_default_limits();
    CHECK(tight.max_sh_degree == 3 && tight.max_bytes > 0);
    tight.max_bytes = 10;
    CHECK(gsc_decode_limited(buf, (size_t)len, &tight, 0, &scene) == GSC_ERR_LIMITS && scene == NULL);
    CHECK(gsc_decode(NULL, 10, 3, 0, &scene) == GSC_ERR_ARGUMENT);
    CHECK(gsc_decode(buf, (size_t)len, 3, 0, NULL) == GSC_ERR_ARGUMENT);
    CHECK(gsc_decode(buf, (size_t)len, 7, 0, &scene) == GSC_ERR_ARGUMENT);
    CHECK(gsc_decode(buf, (size_t)len / 2, 3, 0, &scene) < 0 && scene == NULL);
    CHECK(gsc_scene_count(NULL) == 0 && gsc_scene_positions(NULL) == NULL && gsc_scene_sh_degree(NULL) == -1);
    gsc_scene_free(NULL);

    uint32_t peek_count = 0;
    int peek_degree = -1;
    CHECK(gsc_peek_header(buf, (size_t)len, &peek_count, &peek_degree) == GSC_OK);

    int rc = gsc_decode(buf, (size_t)len, 3, 1, &scene);
    if (rc != GSC_OK) { fprintf(stderr, "decode failed (%d): %s\n", rc, gsc_last_error()); return 1; }
    size_t n = gsc_scene_count(scene);
    int degree = gsc_scene_sh_degree(scene);
    size_t k = gsc_scene_sh_rest_coeffs(scene);
    CHECK(n == peek_count && degree == peek_degree);
    CHECK(k == (size_t)((degree + 1) * (degree + 1) - 1));

    FILE *out = fopen(argv[2], "wb");
    CHECK(out != NULL);
    uint32_t n32 = (uint32_t)n;
    int32_t d32 = degree;
    CHECK(fwrite(&n32, 4, 1, out) == 1 && fwrite(&d32, 4, 1, out) == 1);
    CHECK(dump(out, gsc_scene_positions(scene), n * 3));
    CHECK(dump(out, gsc_scene_log_scales(scene), n * 3));
    CHECK(dump(out, gsc_scene_rotations(scene), n * 4));
    CHECK(dump(out, gsc_scene_opacity_logits(scene), n));
    CHECK(dump(out, gsc_scene_sh_dc(scene), n * 3));
    CHECK(dump(out, gsc_scene_sh_rest(scene), n * k * 3));
    fclose(out);
    gsc_scene_free(scene);
    free(buf);
    printf("decoded %zu Gaussians, SH degree %d, gscodec %s\n", n, degree, gsc_version());
    return 0;
}
