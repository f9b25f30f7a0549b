/* A minimal sphrender stream client in C11 + POSIX sockets, written from PROTOCOL.md alone.
 *
 *   sphr_client HOST PORT OUT_PREFIX [TOKEN]
 *
 * HELLO (scene with output.format = "raw"), WELCOME, then three pipelined FRAMEs of 300
 * particles (positions <f8, radii <f4):
 *   id 1: the session's encoding (raw rgba8)      -> OUT_PREFIX.rgba  (64 x 48 x 4 bytes)
 *   id 2: per-frame override output.format "jpeg" -> OUT_PREFIX.jpg
 *   id 3: one negative radius                     -> ERROR bad_input (not fatal)
 *   id 4: the same particles in the compact encoding (PROTOCOL.md 4.7: positions within
 *         0.0002 of the sent values, predicted particle to particle, radii raw; zstd)
 *                                                 -> OUT_PREFIX.compact.rgba
 *   id 5: the same again, order-free (PROTOCOL.md 4.7 "cells": particles sorted into cells of
 *         2^6 quanta, radii permuted with them); decoded here too before it is sent
 *                                                 -> OUT_PREFIX.cells.rgba
 * then BYE and GOODBYE. The positions sent are written to OUT_PREFIX.positions (N x 3 <f8),
 * those frame 4 decodes to to OUT_PREFIX.compact.positions, those frame 5 decodes to (in the
 * order sent) to OUT_PREFIX.cells.positions and that order (N <i4) to OUT_PREFIX.cells.order,
 * so a test can render the same frames. One line per message on stdout; exit status 0 when every answer was what
 * PROTOCOL.md says it must be. Build with -lzstd (and -ffp-contract=off: the decoder's
 * lo + q * step must be a multiply and an add, each rounded).
 */
#define _POSIX_C_SOURCE 200809L
#include <arpa/inet.h>
#include <math.h>
#include <netdb.h>
#include <netinet/in.h>
#include <netinet/tcp.h>
#include <stdint.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/socket.h>
#include <unistd.h>
#include <zstd.h>

enum { HELLO = 0x01, FRAME = 0x02, BYE = 0x03, WELCOME = 0x81, IMAGE = 0x82, ERROR_MSG = 0x83,
       DROPPED = 0x84, GOODBYE = 0x85 };
enum { N = 300, WIDTH = 64, HEIGHT = 48 };

static int sock = -1;

static void die(const char *what) {
    fprintf(stderr, "sphr_client: %s\n", what);
    exit(1);
}

static void put_u32(uint8_t *p, uint32_t v) {  /* little-endian whatever the host */
    for (int i = 0; i < 4; i++) p[i] = (uint8_t)(v >> (8 * i));
}

static uint32_t get_u32(const uint8_t *p) {
    return (uint32_t)p[0] | (uint32_t)p[1] << 8 | (uint32_t)p[2] << 16 | (uint32_t)p[3] << 24;
}

static void put_f64(uint8_t *p, double d) {
    uint64_t bits;
    memcpy(&bits, &d, 8);
    for (int i = 0; i < 8; i++) p[i] = (uint8_t)(bits >> (8 * i));
}

static void put_f32(uint8_t *p, float f) {
    uint32_t bits;
    memcpy(&bits, &f, 4);
    put_u32(p, bits);
}

static void send_all(const uint8_t *data, size_t n) {
    while (n) {
        ssize_t sent = send(sock, data, n, 0);
        if (sent <= 0) die("send failed");
        data += sent;
        n -= (size_t)sent;
    }
}

static void recv_all(uint8_t *data, size_t n) {
    while (n) {
        ssize_t got = recv(sock, data, n, 0);
        if (got <= 0) die("the server closed the connection mid-message");
        data += got;
        n -= (size_t)got;
    }
}

/* Prefix (16 bytes: "SPHR", version 1, type, flags 0, header length, payload length), header,
 * payload. */
static void send_message(uint8_t type, const char *header, const uint8_t *payload, size_t plen) {
    uint8_t prefix[16] = {'S', 'P', 'H', 'R', 1, type, 0, 0};
    size_t hlen = strlen(header);
    put_u32(prefix + 8, (uint32_t)hlen);
    put_u32(prefix + 12, (uint32_t)plen);
    send_all(prefix, 16);
    send_all((const uint8_t *)header, hlen);
    if (plen) send_all(payload, plen);
}

typedef struct {
    uint8_t type;
    char *header;      /* NUL-terminated JSON text */
    uint8_t *payload;
    uint32_t payload_length;
} Message;

static Message receive_message(void) {
    uint8_t prefix[16];
    recv_all(prefix, 16);
    if (memcmp(prefix, "SPHR", 4) != 0) die("bad magic from the server");
    if (prefix[4] != 1) die("unexpected protocol version");
    Message m = {prefix[5], NULL, NULL, get_u32(prefix + 12)};
    uint32_t hlen = get_u32(prefix + 8);
    m.header = calloc(hlen + 1, 1);
    m.payload = malloc(m.payload_length ? m.payload_length : 1);
    if (!m.header || !m.payload) die("out of memory");
    recv_all((uint8_t *)m.header, hlen);
    recv_all(m.payload, m.payload_length);
    return m;
}

static void free_message(Message *m) {
    free(m->header);
    free(m->payload);
}

/* The text after "key": in a flat JSON header (enough for the server's own headers: keys are
 * unique per object and values we read are numbers, strings, booleans or null). */
static const char *json_value(const char *json, const char *key) {
    char pattern[64];
    snprintf(pattern, sizeof pattern, "\"%s\":", key);
    const char *at = strstr(json, pattern);
    if (!at) return NULL;
    at += strlen(pattern);
    while (*at == ' ') at++;
    return at;
}

static long json_int(const char *json, const char *key) {
    const char *v = json_value(json, key);
    return v ? strtol(v, NULL, 10) : -1;
}

static void json_string(const char *json, const char *key, char *out, size_t size) {
    const char *v = json_value(json, key);
    out[0] = '\0';
    if (!v || *v != '"') {
        snprintf(out, size, "%s", v && strncmp(v, "null", 4) == 0 ? "null" : "?");
        return;
    }
    size_t i = 0;
    for (v++; *v && *v != '"' && i + 1 < size; v++) out[i++] = *v;
    out[i] = '\0';
}

static void write_file(const char *prefix, const char *suffix, const uint8_t *data, size_t n) {
    char path[4096];
    snprintf(path, sizeof path, "%s%s", prefix, suffix);
    FILE *f = fopen(path, "wb");
    if (!f || fwrite(data, 1, n, f) != n || fclose(f) != 0) die("cannot write an output file");
}

/* FRAME payload: positions (N x 3 <f8) then radii (N <f4), no padding. */
static uint8_t payload[N * 3 * 8 + N * 4];

static void make_particles(const char *prefix) {
    uint64_t state = 12345;
    int made = 0;
    while (made < N) {  /* points of a ball of radius 0.15, from a fixed LCG */
        double p[3];
        for (int k = 0; k < 3; k++) {
            state = state * 6364136223846793005ULL + 1442695040888963407ULL;
            p[k] = ((double)(state >> 11) / 9007199254740992.0 * 2.0 - 1.0) * 0.15;
        }
        if (p[0] * p[0] + p[1] * p[1] + p[2] * p[2] > 0.15 * 0.15) continue;
        for (int k = 0; k < 3; k++) put_f64(payload + (made * 3 + k) * 8, p[k]);
        made++;
    }
    for (int i = 0; i < N; i++) put_f32(payload + N * 24 + i * 4, 0.02f);
    write_file(prefix, ".positions", payload, N * 24);
}

/* The compact FRAME of the particles in `payload`: its JSON header into `header`, its payload
 * (two zstd frames) into `*out`; returns the payload's length. */
enum { MAX_COMPACT = 2 * (N * 3 * 8 + N * 4) + 1024 };
static uint8_t planes[N * 3 * 8];
static uint8_t compact[MAX_COMPACT];

static size_t zstd_frame(const uint8_t *data, size_t n, uint8_t *out, size_t room) {
    ZSTD_CCtx *cctx = ZSTD_createCCtx();
    if (!cctx) die("out of memory");
    ZSTD_CCtx_setParameter(cctx, ZSTD_c_checksumFlag, 1);     /* the server requires both */
    ZSTD_CCtx_setParameter(cctx, ZSTD_c_contentSizeFlag, 1);
    size_t written = ZSTD_compress2(cctx, out, room, data, n);
    ZSTD_freeCCtx(cctx);
    if (ZSTD_isError(written)) die("zstd failed");
    return written;
}

static double get_f64(const uint8_t *p) {
    uint64_t bits = 0;
    for (int i = 0; i < 8; i++) bits |= (uint64_t)p[i] << (8 * i);
    double d;
    memcpy(&d, &bits, 8);
    return d;
}

/* q = round((x - lo) / step) per component, nudged so that lo + q * step is within `error`;
 * returns the step. */
static double quantise(double error, int64_t q[3][N], double lo[3], double hi[3]) {
    double p[N][3];
    for (int i = 0; i < N; i++)
        for (int c = 0; c < 3; c++) p[i][c] = get_f64(payload + (i * 3 + c) * 8);
    for (int c = 0; c < 3; c++) {
        lo[c] = hi[c] = p[0][c];
        for (int i = 1; i < N; i++) {
            if (p[i][c] < lo[c]) lo[c] = p[i][c];
            if (p[i][c] > hi[c]) hi[c] = p[i][c];
        }
    }
    const double step = 2.0 * error * (1.0 - 1.0 / 1073741824.0);  /* room for rounding */
    for (int c = 0; c < 3; c++) {
        for (int i = 0; i < N; i++) {
            int64_t k = llround((p[i][c] - lo[c]) / step);
            for (int pass = 0; pass < 2; pass++) {  /* a value one ulp past the bound: nudge */
                double value = lo[c] + (double)k * step, miss = value - p[i][c];
                if (miss > error) k--;
                else if (miss < -error) k++;
            }
            q[c][i] = k;
        }
    }
    return step;
}

static size_t compact_frame(const char *prefix, double error, char *header, size_t hsize) {
    double lo[3], hi[3], decoded[N * 3];
    int64_t q[3][N];
    const double step = quantise(error, q, lo, hi);
    uint64_t top = 0, zz[3][N];
    for (int c = 0; c < 3; c++) {
        for (int i = 0; i < N; i++) {
            int64_t k = q[c][i];
            decoded[i * 3 + c] = lo[c] + (double)k * step;
            int64_t r = k - (i ? q[c][i - 1] : 0);  /* predicted from the previous particle */
            zz[c][i] = ((uint64_t)r << 1) ^ (uint64_t)(r >> 63);  /* zigzag */
            if (zz[c][i] > top) top = zz[c][i];
        }
    }
    int width = top < 256 ? 1 : top < 65536 ? 2 : top < 4294967296ULL ? 4 : 8;
    size_t count = 3 * N;  /* elements, component-major; byte b of each in plane b */
    for (int c = 0; c < 3; c++)
        for (int i = 0; i < N; i++)
            for (int b = 0; b < width; b++)
                planes[b * count + c * N + i] = (uint8_t)(zz[c][i] >> (8 * b));
    size_t first = zstd_frame(planes, count * width, compact, MAX_COMPACT);
    for (int i = 0; i < N; i++)  /* radii raw: 4 planes of the float32 bytes */
        for (int b = 0; b < 4; b++) planes[b * N + i] = payload[N * 24 + i * 4 + b];
    size_t second = zstd_frame(planes, N * 4, compact + first, MAX_COMPACT - first);
    snprintf(header, hsize,
             "{\"id\":4,\"encoding\":\"compact\",\"arrays\":["
             "{\"name\":\"positions\",\"dtype\":\"<f8\",\"shape\":[%d,3],"
             "\"coding\":\"quantized\",\"step\":%.17g,"
             "\"bounds\":[[%.17g,%.17g,%.17g],[%.17g,%.17g,%.17g]],"
             "\"predict\":\"particle\",\"width\":%d,\"bytes\":%zu},"
             "{\"name\":\"radii\",\"dtype\":\"<f4\",\"shape\":[%d],\"coding\":\"raw\","
             "\"bytes\":%zu}]}",
             N, step, lo[0], lo[1], lo[2], hi[0], hi[1], hi[2], width, first, N, second);
    uint8_t bytes[N * 3 * 8];
    for (int i = 0; i < N * 3; i++) put_f64(bytes + i * 8, decoded[i]);
    write_file(prefix, ".compact.positions", bytes, sizeof bytes);
    return first + second;
}

/* Byte planes of n values (of `width` bytes each) into `out`. */
static size_t put_planes(const uint64_t *values, size_t n, int width, uint8_t *out) {
    for (int b = 0; b < width; b++)
        for (size_t i = 0; i < n; i++) out[b * n + i] = (uint8_t)(values[i] >> (8 * b));
    return n * (size_t)width;
}

static uint64_t get_plane_value(const uint8_t *data, size_t n, int width, size_t i) {
    uint64_t v = 0;
    for (int b = 0; b < width; b++) v |= (uint64_t)data[b * n + i] << (8 * b);
    return v;
}

static int bit_length(uint64_t v) {
    int bits = 0;
    while (v) bits++, v >>= 1;
    return bits;
}

static int width_of(uint64_t top) {
    return top < 256 ? 1 : top < 65536 ? 2 : top < 4294967296ULL ? 4 : 8;
}

enum { CELL_BITS = 6 };
static uint64_t cell_number[N];

static int by_cell(const void *a, const void *b) {  /* cell number, then the given order */
    int i = *(const int *)a, j = *(const int *)b;
    if (cell_number[i] != cell_number[j]) return cell_number[i] < cell_number[j] ? -1 : 1;
    return i - j;
}

/* The cells section (gaps, counts when fewer cells than particles, offsets) decoded back to q,
 * in the order sent: what the server will do with it. */
static void decode_cells(const uint8_t *raw, int cells, int width, int count_width,
                         const int grid[3], int64_t out[3][N]) {
    const uint8_t *counts = raw + (size_t)cells * width;
    const uint8_t *offsets = counts + (cells < N ? (size_t)cells * count_width : 0);
    uint64_t number = 0;
    int particle = 0;
    for (int j = 0; j < cells; j++) {
        number += get_plane_value(raw, cells, width, j);
        uint64_t count = cells < N ? get_plane_value(counts, cells, count_width, j) : 1;
        uint64_t cell[3] = {number >> (grid[1] + grid[2]),
                            (number >> grid[2]) & ((1ULL << grid[1]) - 1),
                            number & ((1ULL << grid[2]) - 1)};
        for (uint64_t n = 0; n < count && particle < N; n++, particle++)
            for (int c = 0; c < 3; c++)
                out[c][particle] = (int64_t)(cell[c] << CELL_BITS) + offsets[c * N + particle];
    }
    if (particle != N) die("the cells decode to the wrong particle count");
}

/* The compact FRAME of the particles in `payload` with order-free positions (predict cells),
 * radii raw in the same order; as compact_frame. */
static size_t cells_frame(const char *prefix, double error, char *header, size_t hsize) {
    double lo[3], hi[3], decoded[N * 3];
    int64_t q[3][N], back[3][N];
    const double step = quantise(error, q, lo, hi);
    int grid[3], order[N];
    for (int c = 0; c < 3; c++) {
        int64_t top = 0;
        for (int i = 0; i < N; i++)
            if (q[c][i] >> CELL_BITS > top) top = q[c][i] >> CELL_BITS;
        grid[c] = bit_length((uint64_t)top);
    }
    for (int i = 0; i < N; i++) {
        cell_number[i] = (uint64_t)(q[0][i] >> CELL_BITS) << (grid[1] + grid[2]) |
                         (uint64_t)(q[1][i] >> CELL_BITS) << grid[2] |
                         (uint64_t)(q[2][i] >> CELL_BITS);
        order[i] = i;
    }
    qsort(order, N, sizeof order[0], by_cell);
    static uint64_t gaps[N], counts[N], offsets[3 * N];
    int cells = 0;
    uint64_t previous = 0, top_gap = 0, top_count = 0;
    for (int j = 0; j < N; j++) {
        uint64_t number = cell_number[order[j]];
        if (j == 0 || number != cell_number[order[j - 1]]) {
            gaps[cells] = number - previous;
            counts[cells] = 0;
            previous = number;
            if (gaps[cells] > top_gap) top_gap = gaps[cells];
            cells++;
        }
        if (++counts[cells - 1] > top_count) top_count = counts[cells - 1];
        for (int c = 0; c < 3; c++)
            offsets[c * N + j] = (uint64_t)q[c][order[j]] & ((1u << CELL_BITS) - 1);
    }
    int width = width_of(top_gap), count_width = width_of(top_count);
    size_t n = put_planes(gaps, cells, width, planes);
    if (cells < N) n += put_planes(counts, cells, count_width, planes + n);
    n += put_planes(offsets, 3 * N, 1, planes + n);
    decode_cells(planes, cells, width, count_width, grid, back);
    for (int j = 0; j < N; j++)
        for (int c = 0; c < 3; c++) {
            if (back[c][j] != q[c][order[j]]) die("the cells section does not decode to q");
            decoded[j * 3 + c] = lo[c] + (double)back[c][j] * step;
        }
    size_t first = zstd_frame(planes, n, compact, MAX_COMPACT);
    for (int j = 0; j < N; j++)  /* radii raw, in the order sent */
        for (int b = 0; b < 4; b++) planes[b * N + j] = payload[N * 24 + order[j] * 4 + b];
    size_t second = zstd_frame(planes, N * 4, compact + first, MAX_COMPACT - first);
    char counted[32] = "";
    if (cells < N) snprintf(counted, sizeof counted, ",\"count_width\":%d", count_width);
    snprintf(header, hsize,
             "{\"id\":5,\"encoding\":\"compact\",\"arrays\":["
             "{\"name\":\"positions\",\"dtype\":\"<f8\",\"shape\":[%d,3],"
             "\"coding\":\"quantized\",\"step\":%.17g,"
             "\"bounds\":[[%.17g,%.17g,%.17g],[%.17g,%.17g,%.17g]],"
             "\"predict\":\"cells\",\"cell_bits\":%d,\"grid_bits\":[%d,%d,%d],"
             "\"cells\":%d,\"width\":%d%s,\"bytes\":%zu},"
             "{\"name\":\"radii\",\"dtype\":\"<f4\",\"shape\":[%d],\"coding\":\"raw\","
             "\"bytes\":%zu}]}",
             N, step, lo[0], lo[1], lo[2], hi[0], hi[1], hi[2], CELL_BITS, grid[0], grid[1],
             grid[2], cells, width, counted, first, N, second);
    uint8_t bytes[N * 3 * 8], order_bytes[N * 4];
    for (int i = 0; i < N * 3; i++) put_f64(bytes + i * 8, decoded[i]);
    for (int j = 0; j < N; j++) put_u32(order_bytes + j * 4, (uint32_t)order[j]);
    write_file(prefix, ".cells.positions", bytes, sizeof bytes);
    write_file(prefix, ".cells.order", order_bytes, sizeof order_bytes);
    printf("CELLS cells=%d roundtrip ok\n", cells);
    return first + second;
}

int main(int argc, char **argv) {
    if (argc < 4) {
        fprintf(stderr, "usage: sphr_client HOST PORT OUT_PREFIX [TOKEN]\n");
        return 2;
    }
    const char *prefix = argv[3];
    struct addrinfo hints = {0}, *address;
    hints.ai_family = AF_UNSPEC;
    hints.ai_socktype = SOCK_STREAM;
    if (getaddrinfo(argv[1], argv[2], &hints, &address) != 0) die("cannot resolve the host");
    sock = socket(address->ai_family, address->ai_socktype, address->ai_protocol);
    if (sock < 0 || connect(sock, address->ai_addr, address->ai_addrlen) != 0) die("cannot connect");
    freeaddrinfo(address);
    int one = 1;
    setsockopt(sock, IPPROTO_TCP, TCP_NODELAY, &one, sizeof one);

    char hello[1024];
    snprintf(hello, sizeof hello,
             "{\"scene\":{\"image\":{\"width\":%d,\"height\":%d},"
             "\"camera\":{\"eye\":[0.6,0.5,0.9],\"target\":[0,0,0],\"fov_y\":40},"
             "\"particles\":{\"radius\":0.02},\"output\":{\"format\":\"raw\"}},"
             "\"mode\":\"queue\",\"client\":\"c11 example\"%s%s%s}",
             WIDTH, HEIGHT, argc > 4 ? ",\"token\":\"" : "", argc > 4 ? argv[4] : "",
             argc > 4 ? "\"" : "");
    send_message(HELLO, hello, NULL, 0);
    Message m = receive_message();
    if (m.type != WELCOME) {
        char code[64];
        json_string(m.header, "code", code, sizeof code);
        printf("HELLO refused: %s\n", code);
        return 1;
    }
    long max_in_flight = json_int(m.header, "max_in_flight");
    printf("WELCOME max_in_flight=%ld\n", max_in_flight);
    free_message(&m);
    if (max_in_flight < 5) die("this example pipelines 5 frames");

    make_particles(prefix);
    char frame[512];
    const char *arrays =
        "\"arrays\":[{\"name\":\"positions\",\"dtype\":\"<f8\",\"shape\":[300,3]},"
        "{\"name\":\"radii\",\"dtype\":\"<f4\",\"shape\":[300]}]";
    snprintf(frame, sizeof frame, "{\"id\":1,%s}", arrays);
    send_message(FRAME, frame, payload, sizeof payload);
    snprintf(frame, sizeof frame, "{\"id\":2,%s,\"scene\":{\"output\":{\"format\":\"jpeg\"}}}",
             arrays);
    send_message(FRAME, frame, payload, sizeof payload);
    char compact_header[1024];
    size_t compact_length = compact_frame(prefix, 0.0002, compact_header, sizeof compact_header);
    static uint8_t compact4[MAX_COMPACT];
    memcpy(compact4, compact, compact_length);
    char cells_header[1024];
    size_t cells_length = cells_frame(prefix, 0.0002, cells_header, sizeof cells_header);
    put_f32(payload + N * 24 + 17 * 4, -1.0f);  /* radius 17 < 0: this frame is refused */
    snprintf(frame, sizeof frame, "{\"id\":3,%s}", arrays);
    send_message(FRAME, frame, payload, sizeof payload);
    send_message(FRAME, compact_header, compact4, compact_length);
    send_message(FRAME, cells_header, compact, cells_length);

    int ok = 1;
    for (long id = 1; id <= 5; id++) {
        m = receive_message();
        long got = json_int(m.header, "id");
        char format[32], code[64], field[64];
        if (m.type == IMAGE) {
            json_string(m.header, "format", format, sizeof format);
            long w = json_int(m.header, "width"), h = json_int(m.header, "height");
            printf("IMAGE id=%ld format=%s %ldx%ld bytes=%u\n", got, format, w, h,
                   (unsigned)m.payload_length);
            if (strcmp(format, "raw") == 0) {
                ok &= (id == 1 || id >= 4) && w == WIDTH && h == HEIGHT &&
                      strstr(m.header, "\"u1\"") != NULL &&
                      m.payload_length == (uint32_t)(w * h * 4);
                const char *names[] = {".rgba", "", "", ".compact.rgba", ".cells.rgba"};
                write_file(prefix, names[id - 1], m.payload, m.payload_length);
            } else {
                int soi = m.payload_length > 4 && m.payload[0] == 0xFF && m.payload[1] == 0xD8;
                int eoi = m.payload_length > 4 && m.payload[m.payload_length - 2] == 0xFF &&
                          m.payload[m.payload_length - 1] == 0xD9;
                printf("JPEG markers %s\n", soi && eoi ? "ok" : "bad");
                ok &= id == 2 && strcmp(format, "jpeg") == 0 && soi && eoi;
                write_file(prefix, ".jpg", m.payload, m.payload_length);
            }
        } else if (m.type == ERROR_MSG) {
            json_string(m.header, "code", code, sizeof code);
            json_string(m.header, "field", field, sizeof field);
            const char *fatal = json_value(m.header, "fatal");
            int is_fatal = fatal && strncmp(fatal, "true", 4) == 0;
            printf("ERROR id=%ld code=%s field=%s fatal=%s\n", got, code, field,
                   is_fatal ? "true" : "false");
            ok &= id == 3 && strcmp(code, "bad_input") == 0 && !is_fatal;
        } else {
            printf("unexpected message type 0x%02x\n", m.type);
            ok = 0;
        }
        ok &= got == id;  /* answers come in frame order */
        free_message(&m);
    }
    send_message(BYE, "{}", NULL, 0);
    m = receive_message();
    char reason[32];
    json_string(m.header, "reason", reason, sizeof reason);
    printf("GOODBYE reason=%s\n", m.type == GOODBYE ? reason : "?");
    ok &= m.type == GOODBYE && strcmp(reason, "bye") == 0;
    free_message(&m);
    uint8_t rest;
    ok &= recv(sock, &rest, 1, 0) == 0;  /* then the server closes */
    close(sock);
    printf("%s\n", ok ? "OK" : "FAILED");
    return ok ? 0 : 1;
}
