/*
 * fg_protocol.c - see fg_protocol.h. Mirrors frictiongym/hardware/protocol.py line by line
 * where it can, so that a reader can check one against the other.
 */
#include "fg_protocol.h"

/* ---- CRC-16/CCITT-FALSE -------------------------------------------------------------- */

uint16_t fg_crc16_update(uint16_t crc, uint8_t byte)
{
    uint8_t bit;
    crc ^= (uint16_t)((uint16_t)byte << 8);
    for (bit = 0; bit < 8; bit++) {
        crc = (crc & 0x8000u) ? (uint16_t)((crc << 1) ^ 0x1021u) : (uint16_t)(crc << 1);
    }
    return crc;
}

uint16_t fg_crc16(const uint8_t *data, size_t len)
{
    uint16_t crc = 0xFFFFu;
    size_t i;
    for (i = 0; i < len; i++) {
        crc = fg_crc16_update(crc, data[i]);
    }
    return crc;
}

/* ---- COBS ------------------------------------------------------------------------------ */

size_t fg_cobs_encode(const uint8_t *in, size_t len, uint8_t *out)
{
    size_t n = 1, code_at = 0, i;
    uint8_t code = 1;
    for (i = 0; i < len; i++) {
        if (in[i] != 0) {
            out[n++] = in[i];
            code++;
        }
        if (in[i] == 0 || code == 0xFF) { /* close the block: a zero, or 254 data bytes */
            out[code_at] = code;
            code_at = n++;
            code = 1;
        }
    }
    out[code_at] = code;
    return n;
}

int fg_cobs_decode(const uint8_t *in, size_t len, uint8_t *out, size_t out_size)
{
    size_t i = 0, n = 0, j, end;
    while (i < len) {
        uint8_t code = in[i];
        end = i + code;
        if (code == 0 || end > len) {
            return FG_ERR_COBS;
        }
        for (j = i + 1; j < end; j++) {
            if (in[j] == 0) {
                return FG_ERR_COBS;
            }
            if (n >= out_size) {
                return FG_ERR_BUFFER;
            }
            out[n++] = in[j];
        }
        i = end;
        if (code != 0xFF && i < len) { /* a block shorter than 254 stood for a zero */
            if (n >= out_size) {
                return FG_ERR_BUFFER;
            }
            out[n++] = 0;
        }
    }
    return (int)n;
}

/* ---- little-endian fields ------------------------------------------------------------ */

static void put_u16(uint8_t *p, uint16_t v)
{
    p[0] = (uint8_t)(v & 0xFFu);
    p[1] = (uint8_t)(v >> 8);
}

static void put_u32(uint8_t *p, uint32_t v)
{
    p[0] = (uint8_t)(v & 0xFFu);
    p[1] = (uint8_t)((v >> 8) & 0xFFu);
    p[2] = (uint8_t)((v >> 16) & 0xFFu);
    p[3] = (uint8_t)(v >> 24);
}

static uint16_t get_u16(const uint8_t *p)
{
    return (uint16_t)(p[0] | ((uint16_t)p[1] << 8));
}

static uint32_t get_u32(const uint8_t *p)
{
    return (uint32_t)p[0] | ((uint32_t)p[1] << 8) | ((uint32_t)p[2] << 16) |
           ((uint32_t)p[3] << 24);
}

/* Two's complement without implementation-defined conversions. */
static int16_t to_i16(uint16_t v)
{
    return (v & 0x8000u) ? (int16_t)(-(int32_t)((~v & 0xFFFFu) + 1u)) : (int16_t)v;
}

static int32_t to_i32(uint32_t v)
{
    return (v & 0x80000000UL) ? (int32_t)(-(int32_t)(~v) - 1) : (int32_t)v;
}

#define put_i16(p, v) put_u16((p), (uint16_t)(v))
#define put_i32(p, v) put_u32((p), (uint32_t)(v))

/* ---- messages ------------------------------------------------------------------------ */

size_t fg_pack(const fg_message *msg, uint8_t *p)
{
    p[0] = msg->type;
    switch (msg->type) {
    case FG_COMMAND: {
        const fg_command *c = &msg->u.command;
        p[1] = c->flags;
        put_u16(p + 2, c->seq);
        put_i16(p + 4, c->command);
        put_i16(p + 6, c->aux);
        return FG_COMMAND_SIZE;
    }
    case FG_HELLO_REQUEST:
        p[1] = msg->u.hello_request.version;
        return FG_HELLO_REQUEST_SIZE;
    case FG_PLACE:
        put_u32(p + 1, msg->u.place.position_bits);
        return FG_PLACE_SIZE;
    case FG_HELLO: {
        const fg_hello *h = &msg->u.hello;
        p[1] = h->version;
        p[2] = h->kind;
        p[3] = h->capabilities;
        put_u16(p + 4, h->rate_hz);
        put_u16(p + 6, h->counts_per_rev);
        put_u16(p + 8, h->command_scale);
        put_i16(p + 10, h->command_limit);
        put_u16(p + 12, h->watchdog_ms);
        put_u32(p + 14, h->firmware);
        return FG_HELLO_SIZE;
    }
    case FG_STATE: {
        const fg_state *s = &msg->u.state;
        p[1] = s->status;
        put_u16(p + 2, s->seq);
        put_u32(p + 4, s->tick_us);
        put_u16(p + 8, s->seq_applied);
        put_i16(p + 10, s->applied);
        put_i32(p + 12, s->sensor);
        put_i16(p + 16, s->aux);
        return FG_STATE_SIZE;
    }
    default:
        return 0;
    }
}

int fg_unpack(const uint8_t *p, size_t len, fg_message *msg)
{
    size_t want;
    if (len == 0) {
        return FG_ERR_LENGTH;
    }
    switch (p[0]) {
    case FG_COMMAND: want = FG_COMMAND_SIZE; break;
    case FG_HELLO_REQUEST: want = FG_HELLO_REQUEST_SIZE; break;
    case FG_PLACE: want = FG_PLACE_SIZE; break;
    case FG_HELLO: want = FG_HELLO_SIZE; break;
    case FG_STATE: want = FG_STATE_SIZE; break;
    default: return FG_ERR_TYPE;
    }
    if (len != want) {
        return FG_ERR_LENGTH;
    }
    msg->type = p[0];
    switch (p[0]) {
    case FG_COMMAND:
        msg->u.command.flags = p[1];
        msg->u.command.seq = get_u16(p + 2);
        msg->u.command.command = to_i16(get_u16(p + 4));
        msg->u.command.aux = to_i16(get_u16(p + 6));
        break;
    case FG_HELLO_REQUEST:
        msg->u.hello_request.version = p[1];
        break;
    case FG_PLACE:
        msg->u.place.position_bits = get_u32(p + 1);
        break;
    case FG_HELLO:
        if (p[2] != FG_KIND_ROTARY && p[2] != FG_KIND_ALTINO && p[2] != FG_KIND_AXIS) {
            return FG_ERR_KIND;
        }
        msg->u.hello.version = p[1];
        msg->u.hello.kind = p[2];
        msg->u.hello.capabilities = p[3];
        msg->u.hello.rate_hz = get_u16(p + 4);
        msg->u.hello.counts_per_rev = get_u16(p + 6);
        msg->u.hello.command_scale = get_u16(p + 8);
        msg->u.hello.command_limit = to_i16(get_u16(p + 10));
        msg->u.hello.watchdog_ms = get_u16(p + 12);
        msg->u.hello.firmware = get_u32(p + 14);
        break;
    default: /* FG_STATE: the first switch let nothing else through */
        msg->u.state.status = p[1];
        msg->u.state.seq = get_u16(p + 2);
        msg->u.state.tick_us = get_u32(p + 4);
        msg->u.state.seq_applied = get_u16(p + 8);
        msg->u.state.applied = to_i16(get_u16(p + 10));
        msg->u.state.sensor = to_i32(get_u32(p + 12));
        msg->u.state.aux = to_i16(get_u16(p + 16));
        break;
    }
    return FG_OK;
}

/* ---- frames -------------------------------------------------------------------------- */

size_t fg_encode(const fg_message *msg, uint8_t *frame)
{
    uint8_t data[FG_MAX_PAYLOAD + 2u];
    size_t len = fg_pack(msg, data), n;
    uint16_t crc;
    if (len == 0) {
        return 0;
    }
    crc = fg_crc16(data, len);
    put_u16(data + len, crc);
    n = fg_cobs_encode(data, len + 2u, frame);
    frame[n] = 0x00;
    return n + 1u;
}

int fg_decode(const uint8_t *frame, size_t len, fg_message *msg)
{
    uint8_t data[FG_MAX_FRAME];
    int n;
    if (len > FG_MAX_FRAME) {
        return FG_ERR_LONG;
    }
    n = fg_cobs_decode(frame, len, data, sizeof data);
    if (n < 0) {
        return n;
    }
    if (n < 3) {
        return FG_ERR_SHORT;
    }
    if (fg_crc16(data, (size_t)n - 2u) != get_u16(data + n - 2)) {
        return FG_ERR_CRC;
    }
    return fg_unpack(data, (size_t)n - 2u, msg);
}

/* ---- streaming decoder --------------------------------------------------------------- */

void fg_decoder_init(fg_decoder *dec)
{
    dec->len = 0;
    dec->overflow = 0;
    dec->frames = 0;
    dec->errors = 0;
}

int fg_decoder_push(fg_decoder *dec, uint8_t byte, fg_message *msg)
{
    int ok;
    if (byte != 0x00) {
        if (dec->len < FG_MAX_FRAME) {
            dec->buf[dec->len++] = byte;
        } else {
            dec->overflow = 1; /* garbage without delimiters: keep nothing, stay bounded */
        }
        return 0;
    }
    if (dec->overflow) {
        ok = FG_ERR_LONG;
    } else if (dec->len == 0) {
        return 0; /* back-to-back delimiters: a sender resynchronising */
    } else {
        ok = fg_decode(dec->buf, dec->len, msg);
    }
    dec->len = 0;
    dec->overflow = 0;
    if (ok == FG_OK) {
        dec->frames++;
        return 1;
    }
    dec->errors++;
    return 0;
}
