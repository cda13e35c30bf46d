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
 * reference and gives each constant's source; the values here must equal its. What it cannot
 * measure it bounds (fg_car_bounds: the mass anywhere in [mass_min, mass_max], friction at
 * least friction + viscous v). At every tick, from the sample x (the front IR readout):
 *   d = FG_IR_NUMERATOR / (x + FG_IR_OFFSET) cm        (x <= 0: out of range, no distance)
 *   bound: upper bound of the approach speed, advanced every tick under the largest command
 *          held over the last FG_GUARD_REACTION_PERIODS periods (0 at boot: the car at rest),
 *          speeding up as mass_min, slowing down as mass_max
 *   v = (d_prev - d) / dt, cm/s toward the wall if both samples have a distance (the brake
 *       decision), judged as v + half a count of each reading (d^2 / (966 + d)) / dt + half a
 *       period of acceleration a(u, v) dt / 2 (at most bound, unless v itself is); else bound
 *   a(u, v) = (u - friction - viscous v) / M
 *   over T: travel = min(v T + a T^2 / 2, max(v, v_top) T), v_T = min(v + a T, v_top),
 *           (a <= 0: travel = v T, v_T = v); v_top = (u - friction) / viscous
 *   stop(u) = d - travel - M v_T^2 / (2 (limit + friction) + viscous v_T), the nearer for
 *             M = mass_min and M = mass_max (convex in M: an end of the range is the worst)
 * with T = FG_GUARD_REACTION_PERIODS dt, d the distance; out of range d = FG_GUARD_EDGE_CM
 * and T one period longer (the car may enter the range just after a sample). u is the larger
 * of the command judged and those held over the last FG_GUARD_REACTION_PERIODS periods (the
 * dead time). LIMIT latches when stop(0) <= cfg.limit_cm at a sample, or when stop(u) <=
 * cfg.limit_cm for the forward command u the motor is about to hold (checked whenever the
 * output is computed: on a Command's arrival and at every tick, against the last sample), so
 * that command is not let through (REARM clears LIMIT, unless the latest sample trips it again
 * at once). Before the first sample forward commands are refused (not latched). While LIMIT
 * is latched the motor gets -command_limit (full reverse: the brake) while the car is in range
 * and v (unjudged) > FG_GUARD_STOPPED_SPEED, then min(command, 0): backing away is allowed, forward is
 * refused. The brake acts even when the device is disarmed (e-stop, watchdog, fault): a car
 * that still approaches must not coast into the wall. Maths in binary32 (AVR's double); the
 * Python reference uses binary64, so results can differ only at the boundary. */
#define FG_IR_NUMERATOR 966.0f             /* paper Eq. (1); plants/sensors.py IR_NUMERATOR */
#define FG_IR_OFFSET 45.0f                 /* paper Eq. (1); plants/sensors.py IR_OFFSET */
/* Build reported in Hello: 3 = the guard bounds the speed and the car (2: the predictive
   guard of one nominal car; 1: a fixed readout limit). hardware/firmware.py FIRMWARE_BUILD. */
#define FG_FIRMWARE_BUILD 3u
#define FG_GUARD_LIMIT_CM 1.5f             /* guard.LIMIT_CM: closest approach, cm */
#define FG_GUARD_REACTION_PERIODS 2        /* guard.REACTION_PERIODS: sensing + dead time */
#define FG_GUARD_STOPPED_SPEED 0.5f        /* guard.STOPPED_SPEED, cm/s */
/* guard.EDGE_CM: the nearest distance that reads 0 (round(966 / d - 45) = 0) */
#define FG_GUARD_EDGE_CM (FG_IR_NUMERATOR / (FG_IR_OFFSET + 0.5f))
/* The car's bounds (guard.py CarBounds), defaults of fg_config_altino; a build may define
 * others (-DFG_GUARD_FRICTION=0 for a car on a surface with no friction to speak of), and
 * fg_device_set_car() changes them at run time. */
#ifndef FG_GUARD_MASS_MIN
#define FG_GUARD_MASS_MIN 1.1f             /* guard.MASS_MIN: units s^2/cm (plausible range) */
#endif
#ifndef FG_GUARD_MASS_MAX
#define FG_GUARD_MASS_MAX 5.5f             /* guard.MASS_MAX (docs/altino-model.md) */
#endif
#ifndef FG_GUARD_FRICTION
#define FG_GUARD_FRICTION 150.4f           /* guard.FRICTION: least forward Coulomb, units */
#endif
#ifndef FG_GUARD_VISCOUS
#define FG_GUARD_VISCOUS 10.93f            /* guard.VISCOUS: least viscous slope */
#endif
#ifndef FG_GUARD_NOISE_COUNTS
#define FG_GUARD_NOISE_COUNTS 8.0f         /* guard.IR_NOISE_COUNTS: largest IR noise, counts */
#endif

/* What the distance guard assumes of the car (guard.py CarBounds). */
typedef struct {
    float mass_min; /* lightest plausible effective mass, units s^2/cm (fastest to speed up) */
    float mass_max; /* heaviest (slowest to brake) */
    float friction; /* least Coulomb friction against a forward-moving car, units (0: none) */
    float viscous;  /* least viscous slope, units/(cm/s) (0: none: no top speed) */
    float noise_counts; /* largest IR readout noise, counts (each reading may be off by it) */
} fg_car_bounds;

typedef struct {
    uint8_t kind;            /* enum fg_kind */
    uint8_t capabilities;    /* enum fg_capability; FG_CAP_DISTANCE_LIMIT turns the guard on */
    uint16_t rate_hz;        /* ticks per second */
    uint16_t counts_per_rev; /* encoder counts per revolution (0: none) */
    uint16_t command_scale;  /* command counts per physical unit */
    int16_t command_limit;   /* commands are clipped to +-this, counts */
    uint16_t watchdog_ms;    /* 0: the default, max(3 periods, 100 ms) */
    float limit_cm;          /* the distance guard's closest approach, cm (FG_GUARD_LIMIT_CM) */
    fg_car_bounds car;       /* what the distance guard assumes of the car (FG_GUARD_*) */
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
    float speed;              /* guard: approach speed judged, cm/s (toward the wall > 0) */
    float measured;           /* guard: approach speed the readings show (else the bound) */
    float bound;              /* guard: upper bound of the approach speed, cm/s */
    float dt;                 /* guard: the period, s */
    int16_t held_peak;        /* guard: largest output since the last tick, counts */
    int16_t held[FG_GUARD_REACTION_PERIODS]; /* guard: largest output of the last periods */
    uint8_t sampled;          /* guard: a sample has come (before it, forward is refused) */
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

/* Change the distance guard's bounds of the car at run time (the guard's state is kept). */
void fg_device_set_car(fg_device *dev, const fg_car_bounds *car);

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
