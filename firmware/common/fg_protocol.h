/*
 * fg_protocol.h - the frictiongym device protocol in C99: CRC-16, COBS, messages, frames.
 *
 * This is the C twin of frictiongym/hardware/protocol.py (the reference); docs/protocol.md
 * describes both, and tests/test_firmware.py checks them against each other on the shared
 * vectors in tests/data/protocol_vectors.json.
 *
 * A frame on the wire is COBS(payload + CRC16) + 0x00:
 *   - payload: one message, little-endian, its type byte first;
 *   - CRC16:   CRC-16/CCITT-FALSE (poly 0x1021, init 0xFFFF, no reflection, no final xor)
 *              of the payload, appended low byte first;
 *   - COBS:    Cheshire & Baker (1999) byte stuffing, so 0x00 only ever delimits frames.
 *
 * No malloc, no Arduino headers, fixed-size buffers; every multi-byte field is assembled
 * byte by byte (no struct punning), so the code is independent of the MCU's endianness.
 */
#ifndef FG_PROTOCOL_H
#define FG_PROTOCOL_H

#include <stddef.h>
#include <stdint.h>

#ifdef __cplusplus
extern "C" {
#endif

/* Version carried by HelloRequest and Hello (protocol.PROTOCOL_VERSION). */
#define FG_PROTOCOL_VERSION 1u
/* Longest payload plus CRC any frame may carry (protocol.MAX_PAYLOAD). */
#define FG_MAX_PAYLOAD 32u
/* Longest encoded frame without its delimiter (protocol.MAX_FRAME = 35). */
#define FG_MAX_FRAME (FG_MAX_PAYLOAD + 2u + FG_MAX_PAYLOAD / 254u + 1u)
/* Buffer size that holds any encoded frame with its 0x00 delimiter. */
#define FG_FRAME_BUFFER (FG_MAX_FRAME + 1u)
/* Bytes that COBS-encoding n bytes may need (one code byte per 254, plus one). */
#define FG_COBS_MAX(n) ((n) + (n) / 254u + 1u)

/* Message types: the first payload byte. */
enum fg_type {
    FG_COMMAND = 0x01,       /* host -> device */
    FG_HELLO_REQUEST = 0x02, /* host -> device */
    FG_PLACE = 0x03,         /* host -> emulator (firmware ignores it) */
    FG_HELLO = 0x80,         /* device -> host */
    FG_STATE = 0x81          /* device -> host, one per tick */
};

/* Payload sizes, type byte included, CRC excluded. */
enum fg_size {
    FG_COMMAND_SIZE = 8,
    FG_HELLO_REQUEST_SIZE = 2,
    FG_PLACE_SIZE = 5,
    FG_HELLO_SIZE = 18,
    FG_STATE_SIZE = 18
};

/* Device kinds (Hello.kind). */
/* FG_KIND_AXIS: a device described by a file (docs/devices.md); the host holds the file. */
enum fg_kind { FG_KIND_ROTARY = 1, FG_KIND_ALTINO = 2, FG_KIND_AXIS = 3 };

/* Command.flags bits. */
enum fg_flag {
    FG_FLAG_ENABLE = 0x01,        /* drive the motor (else zero, amplifier disabled) */
    FG_FLAG_ZERO_POSITION = 0x02, /* zero the encoder now (servo) */
    FG_FLAG_ESTOP = 0x04,         /* zero the motor and disarm until REARM */
    FG_FLAG_REARM = 0x08          /* clear latched WATCHDOG / LIMIT / e-stop, arm */
};

/* State.status bits. */
enum fg_status {
    FG_STATUS_AMP_FAULT = 0x01,
    FG_STATUS_STALL = 0x02,
    FG_STATUS_STALL_ERROR = 0x04,
    FG_STATUS_WATCHDOG = 0x08,     /* latched until REARM */
    FG_STATUS_COMMAND_LATE = 0x10, /* no new command this period: the last one was held */
    FG_STATUS_CRC_ERROR = 0x20,    /* a bad frame arrived since the last State */
    FG_STATUS_LIMIT = 0x40,        /* distance guard tripped; latched until REARM */
    FG_STATUS_DISABLED = 0x80      /* the motor is off: not armed or not enabled */
};

/* Hello.capabilities bits. */
enum fg_capability {
    FG_CAP_WATCHDOG = 0x01,
    FG_CAP_PLACE = 0x02,
    FG_CAP_DISTANCE_LIMIT = 0x04
};

/* Why a frame was rejected (negative return values). */
enum fg_error {
    FG_OK = 0,
    FG_ERR_COBS = -1,   /* a COBS block code is zero or runs past the end */
    FG_ERR_SHORT = -2,  /* fewer than 3 bytes: no room for a payload and its CRC */
    FG_ERR_CRC = -3,    /* CRC mismatch */
    FG_ERR_TYPE = -4,   /* unknown message type */
    FG_ERR_LENGTH = -5, /* payload length does not match its type */
    FG_ERR_KIND = -6,   /* Hello names an unknown device kind */
    FG_ERR_LONG = -7,   /* frame longer than FG_MAX_FRAME */
    FG_ERR_BUFFER = -8  /* caller's output buffer too small */
};

typedef struct {
    uint8_t flags;   /* enum fg_flag */
    uint16_t seq;    /* host sequence number, echoed as State.seq_applied */
    int16_t command; /* counts: mV (servo) or motor units (Altino) */
    int16_t aux;
} fg_command;

typedef struct {
    uint8_t version;
} fg_hello_request;

typedef struct {
    uint32_t position_bits; /* IEEE-754 binary32 bits of the position (rad, or cm) */
} fg_place;

typedef struct {
    uint8_t version;
    uint8_t kind;         /* enum fg_kind */
    uint8_t capabilities; /* enum fg_capability */
    uint16_t rate_hz;
    uint16_t counts_per_rev;
    uint16_t command_scale; /* command counts per physical unit */
    int16_t command_limit;  /* largest |command| applied, counts */
    uint16_t watchdog_ms;   /* 0: no watchdog */
    uint32_t firmware;      /* build number */
} fg_hello;

typedef struct {
    uint8_t status;       /* enum fg_status */
    uint16_t seq;         /* device frame counter */
    uint32_t tick_us;     /* device clock at the sample, wraps at 2^32 */
    uint16_t seq_applied; /* seq of the command held over the period ending here */
    int16_t applied;      /* that command as the motor holds it, counts */
    int32_t sensor;       /* encoder counts, or IR readout 0..800 */
    int16_t aux;          /* motor current mA (servo), or 0 */
} fg_state;

/* One decoded message: `type` says which member of `u` is valid. */
typedef struct {
    uint8_t type;
    union {
        fg_command command;
        fg_hello_request hello_request;
        fg_place place;
        fg_hello hello;
        fg_state state;
    } u;
} fg_message;

/* CRC-16/CCITT-FALSE: start from 0xFFFF, update byte by byte (check: "123456789" -> 0x29B1). */
uint16_t fg_crc16_update(uint16_t crc, uint8_t byte);
uint16_t fg_crc16(const uint8_t *data, size_t len);

/* COBS-encode len bytes into out (FG_COBS_MAX(len) bytes); returns the encoded length. */
size_t fg_cobs_encode(const uint8_t *in, size_t len, uint8_t *out);
/* Decode a COBS block sequence (no delimiter) into out (out_size bytes); returns the decoded
 * length, or FG_ERR_COBS / FG_ERR_BUFFER. */
int fg_cobs_decode(const uint8_t *in, size_t len, uint8_t *out, size_t out_size);

/* The payload of msg into payload (FG_MAX_PAYLOAD bytes); returns its length, 0 if the type
 * is unknown. */
size_t fg_pack(const fg_message *msg, uint8_t *payload);
/* Parse a payload (no CRC); returns FG_OK or FG_ERR_TYPE / FG_ERR_LENGTH / FG_ERR_KIND. */
int fg_unpack(const uint8_t *payload, size_t len, fg_message *msg);

/* The frame of msg with its 0x00 delimiter into frame (FG_FRAME_BUFFER bytes); returns its
 * length, 0 if the type is unknown. */
size_t fg_encode(const fg_message *msg, uint8_t *frame);
/* Parse one frame without its delimiter; returns FG_OK or a negative enum fg_error. */
int fg_decode(const uint8_t *frame, size_t len, fg_message *msg);

/* Byte-at-a-time frame splitter: feed it every received byte (from a UART ISR or loop). */
typedef struct {
    uint8_t buf[FG_MAX_FRAME];
    uint8_t len;
    uint8_t overflow; /* the current frame outgrew buf: it will be counted as one error */
    uint32_t frames;  /* good frames decoded */
    uint32_t errors;  /* frames dropped for bad COBS, CRC, layout or length */
} fg_decoder;

void fg_decoder_init(fg_decoder *dec);
/* Feed one byte; returns 1 and fills msg when it completes a good frame, else 0. */
int fg_decoder_push(fg_decoder *dec, uint8_t byte, fg_message *msg);

#ifdef __cplusplus
}
#endif

#endif /* FG_PROTOCOL_H */
