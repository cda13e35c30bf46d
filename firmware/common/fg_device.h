/*
 * fg_device.h - the device state machine both reference firmwares share (no hardware here).
 *
 * The firmware owns the clock, the motor driver and the sensor; this module owns the rules:
 * arming, ENABLE, the e-stop latch, the watchdog, COMMAND_LATE, CRC_ERROR, the Altino's
 * distance guard, command clipping, Hello and one State frame per tick. docs/protocol.md
 * ("Device behaviour") is the specification; frictiongym/hardware/firmware.py implements the
 * same rules in Python, and tests/test_firmware.py runs the scenario table of
 * tests/data/protocol_vectors.json on both.
 *
 * Use (see firmware/altino/altino.ino and firmware/qube_bridge/qube_bridge.ino):
 *
 *     fg_device dev;
 *     fg_device_config cfg = fg_config_rotary();
 *     fg_device_init(&dev, &cfg);
 *     loop:
 *       while (a byte b arrived) {
 *         uint8_t act = fg_device_rx(&dev, b, micros());
 *         if (act & FG_ACT_ZERO)  zero the encoder;
 *         if (act & FG_ACT_MOTOR) write fg_device_motor(&dev), fg_device_amp_enabled(&dev);
 *         if (act & FG_ACT_HELLO) send fg_device_hello(&dev, frame) bytes;
 *       }
 *       at every tick (absolute deadlines, next += period):
 *         sample the sensor; n = fg_device_tick(&dev, now, sensor, aux, hw_status, frame);
 *         write fg_device_motor(&dev) (a watchdog trip may have zeroed it, the distance
 *         guard may brake);
 *         send the n bytes of frame.
 *
 * Times are device microseconds (micros()); differences are taken modulo 2^32, so the
 * 71-minute wrap of a 32-bit microsecond clock is harmless.
 */
#ifndef FG_DEVICE_H
#define FG_DEVICE_H

#include "fg_protocol.h"

#ifdef __cplusplus
extern "C" {
#endif

/* Actions fg_device_rx / fg_device_receive ask the firmware to take at once. */
enum fg_action {
    FG_ACT_MOTOR = 0x01, /* a Command arrived: write the motor output (and amplifier enable) */
    FG_ACT_ZERO = 0x02,  /* ZERO_POSITION: zero the encoder count now */
    FG_ACT_HELLO = 0x04  /* HelloRequest: send fg_device_hello() now */
};

/* Watchdog floor: the watchdog is max(3 periods, 100 ms). The floor is the host's margin: a
 * general-purpose host under load stalls for tens of ms now and then, and a stall is not a dead
 * host (docs/hardware.md, "Timing and the watchdog"; hardware/firmware.py has the same rule). */
#define FG_WATCHDOG_MIN_MS 100u
#define FG_WATCHDOG_PERIODS 3u

/* Altino distance guard (FG_CAP_DISTANCE_LIMIT). frictiongym/hardware/guard.py is the
 * reference and gives each constant's source; the values here must equal its. At every tick,
 * from the sample x (the front IR readout):
 *   d = FG_IR_NUMERATOR / (x + FG_IR_OFFSET) cm        (x <= 0: out of range, no distance)
 *   v = (d_prev - d) / dt, cm/s toward the wall        (0 unless both samples have a distance)
 *   T = FG_GUARD_REACTION_PERIODS * dt, v+ = max(v, 0),
 *   a = max(u - FG_GUARD_FRICTION, 0) / FG_GUARD_MASS for the command u about to be held
 *   stop(u) = d - (v+ T + a T^2 / 2) - (v+ + a T)^2 / (2 FG_GUARD_BRAKE_DECELERATION)
 *                                                      (stop = d when v+ = 0 and a = 0)
 * and LIMIT latches when stop(0) <= cfg.limit_cm at a sample, or when stop(u) <= cfg.limit_cm
 * for the forward command u the motor is about to hold (checked whenever the output is
 * computed: on a Command's arrival and at every tick, against the last sample), so that
 * command is not let through (REARM clears LIMIT, unless the latest sample trips it again at
 * once). While LIMIT is latched the motor gets -command_limit (full reverse: the
 * brake) while v > FG_GUARD_STOPPED_SPEED, then min(command, 0): backing away is allowed,
 * forward is refused. The brake acts even when the device is disarmed (e-stop, watchdog,
 * fault): a car that still approaches must not coast into the wall. Maths in binary32 (AVR's
 * double); the Python reference uses binary64, so results can differ only at the boundary. */
#define FG_IR_NUMERATOR 966.0f             /* paper Eq. (1); plants/sensors.py IR_NUMERATOR */
#define FG_IR_OFFSET 45.0f                 /* paper Eq. (1); plants/sensors.py IR_OFFSET */
/* Build reported in Hello: 2 = the predictive distance guard (build 1: a fixed readout limit).
   frictiongym/hardware/firmware.py FIRMWARE_BUILD is the same number. */
#define FG_FIRMWARE_BUILD 2u
#define FG_GUARD_LIMIT_CM 1.5f             /* guard.LIMIT_CM: closest approach, cm */
#define FG_GUARD_BRAKE_DECELERATION 300.0f /* guard.BRAKE_DECELERATION, cm/s^2 */
#define FG_GUARD_REACTION_PERIODS 2        /* guard.REACTION_PERIODS: sensing + dead time */
#define FG_GUARD_STOPPED_SPEED 0.5f        /* guard.STOPPED_SPEED, cm/s */
#define FG_GUARD_MASS 2.2f                 /* guard.MASS: units s^2/cm (assumed; guard.py) */
#define FG_GUARD_FRICTION 150.4f           /* guard.FRICTION: least forward friction, units */

typedef struct {
    uint8_t kind;            /* enum fg_kind */
    uint8_t capabilities;    /* enum fg_capability; FG_CAP_DISTANCE_LIMIT turns the guard on */
    uint16_t rate_hz;        /* ticks per second */
    uint16_t counts_per_rev; /* encoder counts per revolution (0: none) */
    uint16_t command_scale;  /* command counts per physical unit */
    int16_t command_limit;   /* commands are clipped to +-this, counts */
    uint16_t watchdog_ms;    /* 0: the default, max(3 periods, 100 ms) */
    float limit_cm;          /* the distance guard's closest approach, cm (FG_GUARD_LIMIT_CM) */
    uint32_t firmware;       /* build number reported in Hello */
} fg_device_config;

typedef struct {
    fg_device_config cfg;
    fg_decoder decoder;
    uint32_t watchdog_us;
    uint32_t last_command_us; /* arrival time of the newest Command */
    uint32_t errors_reported; /* decoder.errors when the last State was built */
    uint16_t seq;             /* State frames sent (the first State has seq 1) */
    uint16_t seq_applied;     /* seq of the newest Command (0 before any) */
    int16_t requested;        /* newest command, clipped */
    int16_t motor;            /* the output the motor holds now (negative while braking) */
    int32_t sensor;           /* last sample */
    float distance;           /* guard: distance of the last sample, cm; < 0: out of range */
    float speed;              /* guard: approach speed, cm/s (toward the wall > 0) */
    uint8_t armed;            /* REARM received and no e-stop, watchdog or fault since */
    uint8_t enabled;          /* ENABLE bit of the newest Command */
    uint8_t fresh;            /* a Command arrived since the last tick */
    uint8_t latched;          /* FG_STATUS_WATCHDOG | FG_STATUS_LIMIT */
} fg_device;

/* Defaults of the two reference devices (each value cites its source in fg_device.c). */
fg_device_config fg_config_rotary(void);
fg_device_config fg_config_altino(void);

/* The watchdog time of cfg in ms: cfg->watchdog_ms, or max(3 periods, 100 ms) when 0. */
uint16_t fg_watchdog_ms(const fg_device_config *cfg);

/* Boot state: not armed, motor 0 (Status.DISABLED). */
void fg_device_init(fg_device *dev, const fg_device_config *cfg);

/* Feed one received byte at time now_us; returns enum fg_action bits. */
uint8_t fg_device_rx(fg_device *dev, uint8_t byte, uint32_t now_us);

/* Act on one decoded message at time now_us; returns enum fg_action bits. */
uint8_t fg_device_receive(fg_device *dev, const fg_message *msg, uint32_t now_us);

/* The tick at now_us with a fresh sample: run the watchdog, report the output held over the
 * period that ends now, feed the sample to the distance guard (its output is the motor's for
 * the next period), write the State frame (with its 0x00) into frame (FG_FRAME_BUFFER bytes);
 * returns its length. If state is not NULL it receives the State as well. */
size_t fg_device_tick(fg_device *dev, uint32_t now_us, int32_t sensor, int16_t aux,
                      uint8_t hw_status, uint8_t *frame, fg_state *state);

/* The Hello frame (with its 0x00) into frame; returns its length. */
size_t fg_device_hello(const fg_device *dev, uint8_t *frame);

/* Motor output now, counts (0 unless armed and enabled, or the distance guard brakes), and
 * whether to enable the amplifier (armed and enabled, or a non-zero output). */
int16_t fg_device_motor(const fg_device *dev);
uint8_t fg_device_amp_enabled(const fg_device *dev);

/* Disarm and recompute the motor (firmware-side e-stop: a button, a fault the MCU detects):
 * 0, unless the distance guard brakes a car that still approaches the wall. */
void fg_device_estop(fg_device *dev);

#ifdef __cplusplus
}
#endif

#endif /* FG_DEVICE_H */
