/*
 * host_harness.c - drives firmware/common on the host for tests/test_firmware.py.
 *
 * Reads one request per line on stdin and answers with zero or more lines followed by a
 * line holding a single ".". Byte strings are hex ("-" for none); numbers are decimal.
 *
 *   crc HEX                      -> crc XXXX
 *   cobs_encode HEX              -> HEX
 *   cobs_decode HEX              -> HEX | err CODE
 *   encode TYPE V...             -> PAYLOAD_HEX CRC_XXXX WIRE_HEX   (V: fields in wire order;
 *                                   Place takes its binary32 bits)
 *   decode HEX                   -> msg TYPE V... | err CODE        (frame without delimiter)
 *   stream HEX                   -> msg TYPE V... per good frame, then count FRAMES ERRORS
 *   dev_init rotary|altino WD_MS -> ok                               (WD_MS 0: the default)
 *   dev_rx T_US HEX              -> act BITS motor M amp E [hello HEX]
 *   dev_tick T_US SENSOR AUX HW  -> state FRAME_HEX, motor M amp E
 *   dev_estop                    -> motor M amp E
 *   dev_car MMIN MMAX FRIC VISC NOISE  -> ok      (fg_device_set_car: the guard's bounds of the car)
 *
 * Not part of any firmware: it uses stdio and a large static line buffer.
 */
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "../common/fg_device.h"
#include "../common/fg_protocol.h"

#define LINE_MAX_CHARS 262144
#define BYTES_MAX (LINE_MAX_CHARS / 2)

static char line[LINE_MAX_CHARS];
static uint8_t bytes[BYTES_MAX];
static uint8_t out[BYTES_MAX + BYTES_MAX / 254 + 16];
static fg_device dev;

static int hex_value(char c)
{
    if (c >= '0' && c <= '9') return c - '0';
    if (c >= 'a' && c <= 'f') return c - 'a' + 10;
    if (c >= 'A' && c <= 'F') return c - 'A' + 10;
    return -1;
}

/* Parse a hex token ("-" is empty); returns the byte count, or -1. */
static long parse_hex(const char *tok, uint8_t *dst, size_t cap)
{
    size_t n = 0, len;
    if (tok == NULL || strcmp(tok, "-") == 0) return 0;
    len = strlen(tok);
    if (len % 2 != 0 || len / 2 > cap) return -1;
    for (n = 0; n < len / 2; n++) {
        int hi = hex_value(tok[2 * n]), lo = hex_value(tok[2 * n + 1]);
        if (hi < 0 || lo < 0) return -1;
        dst[n] = (uint8_t)(hi * 16 + lo);
    }
    return (long)n;
}

static void print_hex(const uint8_t *data, size_t len)
{
    size_t i;
    if (len == 0) fputs("-", stdout);
    for (i = 0; i < len; i++) printf("%02x", data[i]);
}

static long next_long(void)
{
    const char *tok = strtok(NULL, " \t\r\n");
    return tok ? strtol(tok, NULL, 10) : 0;
}

static float next_float(void)
{
    const char *tok = strtok(NULL, " \t\r\n");
    return tok ? (float)strtod(tok, NULL) : 0.0f;
}

static unsigned long next_ulong(void)
{
    const char *tok = strtok(NULL, " \t\r\n");
    return tok ? strtoul(tok, NULL, 10) : 0;
}

static void print_message(const fg_message *m)
{
    printf("msg %u", (unsigned)m->type);
    switch (m->type) {
    case FG_COMMAND:
        printf(" %u %u %d %d", (unsigned)m->u.command.flags, (unsigned)m->u.command.seq,
               (int)m->u.command.command, (int)m->u.command.aux);
        break;
    case FG_HELLO_REQUEST:
        printf(" %u", (unsigned)m->u.hello_request.version);
        break;
    case FG_PLACE:
        printf(" %lu", (unsigned long)m->u.place.position_bits);
        break;
    case FG_HELLO:
        printf(" %u %u %u %u %u %u %d %u %lu", (unsigned)m->u.hello.version,
               (unsigned)m->u.hello.kind, (unsigned)m->u.hello.capabilities,
               (unsigned)m->u.hello.rate_hz, (unsigned)m->u.hello.counts_per_rev,
               (unsigned)m->u.hello.command_scale, (int)m->u.hello.command_limit,
               (unsigned)m->u.hello.watchdog_ms, (unsigned long)m->u.hello.firmware);
        break;
    default:
        printf(" %u %u %lu %u %d %ld %d", (unsigned)m->u.state.status, (unsigned)m->u.state.seq,
               (unsigned long)m->u.state.tick_us, (unsigned)m->u.state.seq_applied,
               (int)m->u.state.applied, (long)m->u.state.sensor, (int)m->u.state.aux);
        break;
    }
    putchar('\n');
}

/* Fill a message from TYPE and its fields in wire order (the rest of the line). */
static void read_message(fg_message *m)
{
    m->type = (uint8_t)next_ulong();
    switch (m->type) {
    case FG_COMMAND:
        m->u.command.flags = (uint8_t)next_ulong();
        m->u.command.seq = (uint16_t)next_ulong();
        m->u.command.command = (int16_t)next_long();
        m->u.command.aux = (int16_t)next_long();
        break;
    case FG_HELLO_REQUEST:
        m->u.hello_request.version = (uint8_t)next_ulong();
        break;
    case FG_PLACE:
        m->u.place.position_bits = (uint32_t)next_ulong();
        break;
    case FG_HELLO:
        m->u.hello.version = (uint8_t)next_ulong();
        m->u.hello.kind = (uint8_t)next_ulong();
        m->u.hello.capabilities = (uint8_t)next_ulong();
        m->u.hello.rate_hz = (uint16_t)next_ulong();
        m->u.hello.counts_per_rev = (uint16_t)next_ulong();
        m->u.hello.command_scale = (uint16_t)next_ulong();
        m->u.hello.command_limit = (int16_t)next_long();
        m->u.hello.watchdog_ms = (uint16_t)next_ulong();
        m->u.hello.firmware = (uint32_t)next_ulong();
        break;
    default:
        m->u.state.status = (uint8_t)next_ulong();
        m->u.state.seq = (uint16_t)next_ulong();
        m->u.state.tick_us = (uint32_t)next_ulong();
        m->u.state.seq_applied = (uint16_t)next_ulong();
        m->u.state.applied = (int16_t)next_long();
        m->u.state.sensor = (int32_t)next_long();
        m->u.state.aux = (int16_t)next_long();
        break;
    }
}

static void print_motor(void)
{
    printf("motor %d amp %u\n", (int)fg_device_motor(&dev), (unsigned)fg_device_amp_enabled(&dev));
}

static void handle(char *cmd)
{
    fg_message msg;
    long n;
    size_t i, len;
    int rc;
    if (strcmp(cmd, "crc") == 0) {
        n = parse_hex(strtok(NULL, " \t\r\n"), bytes, BYTES_MAX);
        if (n < 0) { puts("bad hex"); return; }
        printf("crc %04x\n", (unsigned)fg_crc16(bytes, (size_t)n));
    } else if (strcmp(cmd, "cobs_encode") == 0) {
        n = parse_hex(strtok(NULL, " \t\r\n"), bytes, BYTES_MAX);
        if (n < 0) { puts("bad hex"); return; }
        print_hex(out, fg_cobs_encode(bytes, (size_t)n, out));
        putchar('\n');
    } else if (strcmp(cmd, "cobs_decode") == 0) {
        n = parse_hex(strtok(NULL, " \t\r\n"), bytes, BYTES_MAX);
        if (n < 0) { puts("bad hex"); return; }
        rc = fg_cobs_decode(bytes, (size_t)n, out, sizeof out);
        if (rc < 0) { printf("err %d\n", rc); return; }
        print_hex(out, (size_t)rc);
        putchar('\n');
    } else if (strcmp(cmd, "encode") == 0) {
        read_message(&msg);
        len = fg_pack(&msg, bytes);
        print_hex(bytes, len);
        printf(" %04x ", (unsigned)fg_crc16(bytes, len));
        print_hex(out, fg_encode(&msg, out));
        putchar('\n');
    } else if (strcmp(cmd, "decode") == 0) {
        n = parse_hex(strtok(NULL, " \t\r\n"), bytes, BYTES_MAX);
        if (n < 0) { puts("bad hex"); return; }
        rc = fg_decode(bytes, (size_t)n, &msg);
        if (rc != FG_OK) { printf("err %d\n", rc); return; }
        print_message(&msg);
    } else if (strcmp(cmd, "stream") == 0) {
        fg_decoder dec;
        n = parse_hex(strtok(NULL, " \t\r\n"), bytes, BYTES_MAX);
        if (n < 0) { puts("bad hex"); return; }
        fg_decoder_init(&dec);
        for (i = 0; i < (size_t)n; i++) {
            if (fg_decoder_push(&dec, bytes[i], &msg)) print_message(&msg);
        }
        printf("count %lu %lu\n", (unsigned long)dec.frames, (unsigned long)dec.errors);
    } else if (strcmp(cmd, "dev_init") == 0) {
        const char *kind = strtok(NULL, " \t\r\n");
        fg_device_config cfg = (kind && strcmp(kind, "altino") == 0) ? fg_config_altino()
                                                                      : fg_config_rotary();
        cfg.watchdog_ms = (uint16_t)next_ulong();
        fg_device_init(&dev, &cfg);
        puts("ok");
    } else if (strcmp(cmd, "dev_rx") == 0) {
        uint32_t now = (uint32_t)next_ulong();
        uint8_t act = 0;
        n = parse_hex(strtok(NULL, " \t\r\n"), bytes, BYTES_MAX);
        if (n < 0) { puts("bad hex"); return; }
        for (i = 0; i < (size_t)n; i++) act |= fg_device_rx(&dev, bytes[i], now);
        printf("act %u ", (unsigned)act);
        print_motor();
        if (act & FG_ACT_HELLO) {
            fputs("hello ", stdout);
            print_hex(out, fg_device_hello(&dev, out));
            putchar('\n');
        }
    } else if (strcmp(cmd, "dev_tick") == 0) {
        uint32_t now = (uint32_t)next_ulong();
        int32_t sensor = (int32_t)next_long();
        int16_t aux = (int16_t)next_long();
        uint8_t hw = (uint8_t)next_ulong();
        len = fg_device_tick(&dev, now, sensor, aux, hw, out, NULL);
        fputs("state ", stdout);
        print_hex(out, len);
        putchar('\n');
        print_motor();
    } else if (strcmp(cmd, "dev_car") == 0) {
        fg_car_bounds car;
        car.mass_min = next_float();
        car.mass_max = next_float();
        car.friction = next_float();
        car.viscous = next_float();
        car.noise_counts = next_float();
        fg_device_set_car(&dev, &car);
        puts("ok");
    } else if (strcmp(cmd, "dev_estop") == 0) {
        fg_device_estop(&dev);
        print_motor();
    } else {
        printf("unknown request %s\n", cmd);
    }
}

int main(void)
{
    fg_device_config cfg = fg_config_rotary();
    fg_device_init(&dev, &cfg);
    while (fgets(line, sizeof line, stdin) != NULL) {
        char *cmd = strtok(line, " \t\r\n");
        if (cmd != NULL) {
            if (strcmp(cmd, "quit") == 0) break;
            handle(cmd);
        }
        puts(".");
        fflush(stdout);
    }
    return 0;
}
