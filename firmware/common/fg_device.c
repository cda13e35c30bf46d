/*
 * fg_device.c - see fg_device.h; the rules are specified in docs/protocol.md.
 */
#include "fg_device.h"

fg_device_config fg_config_rotary(void)
{
    fg_device_config cfg;
    cfg.kind = FG_KIND_ROTARY;
    cfg.capabilities = FG_CAP_WATCHDOG;
    /* 500 Hz: Quanser's usual QUBE-Servo 2 rate (QUARC models use Ts = 2 ms). */
    cfg.rate_hz = 500u;
    /* 512-line encoder in quadrature (Quanser datasheet; plants/sensors.py). */
    cfg.counts_per_rev = 2048u;
    /* Commands in mV: 1000 counts per V (protocol.py, Hello.command_scale). */
    cfg.command_scale = 1000u;
    /* +-10 V: the safe envelope of the QUBE's amplifier (presets.py). */
    cfg.command_limit = 10000;
    cfg.watchdog_ms = 0u; /* default: max(3 periods, 100 ms) = 100 ms */
    cfg.limit_cm = 0.0f;  /* unused: no FG_CAP_DISTANCE_LIMIT */
    cfg.car.mass_min = cfg.car.mass_max = 1.0f; /* unused */
    cfg.car.friction = cfg.car.viscous = cfg.car.noise_counts = 0.0f;
    cfg.firmware = FG_FIRMWARE_BUILD;
    return cfg;
}

fg_device_config fg_config_altino(void)
{
    fg_device_config cfg;
    cfg.kind = FG_KIND_ALTINO;
    cfg.capabilities = FG_CAP_WATCHDOG | FG_CAP_DISTANCE_LIMIT;
    /* 20 Hz: one drive frame and one sensor poll per period (presets.ALTINO_DT). */
    cfg.rate_hz = 20u;
    cfg.counts_per_rev = 0u;   /* no encoder: the sensor is the front IR readout */
    cfg.command_scale = 1u;    /* motor units, as Go() takes them */
    cfg.command_limit = 1000;  /* Go() clamps to +-1000 (vendor library) */
    cfg.watchdog_ms = 0u;      /* default: max(3 periods, 100 ms) = 150 ms */
    cfg.limit_cm = FG_GUARD_LIMIT_CM; /* guard.LIMIT_CM (assumed; see guard.py) */
    /* guard.CarBounds: the plausible mass range and the paper's least friction (guard.py) */
    cfg.car.mass_min = FG_GUARD_MASS_MIN;
    cfg.car.mass_max = FG_GUARD_MASS_MAX;
    cfg.car.friction = FG_GUARD_FRICTION;
    cfg.car.viscous = FG_GUARD_VISCOUS;
    cfg.car.noise_counts = FG_GUARD_NOISE_COUNTS;
    cfg.firmware = FG_FIRMWARE_BUILD;
    return cfg;
}

uint16_t fg_watchdog_ms(const fg_device_config *cfg)
{
    uint32_t periods;
    if (cfg->watchdog_ms != 0u) {
        return cfg->watchdog_ms;
    }
    /* ceil(3000 / rate) ms, at least 100 ms */
    periods = (FG_WATCHDOG_PERIODS * 1000UL + cfg->rate_hz - 1u) / cfg->rate_hz;
    return (uint16_t)(periods > FG_WATCHDOG_MIN_MS ? periods : FG_WATCHDOG_MIN_MS);
}

void fg_device_init(fg_device *dev, const fg_device_config *cfg)
{
    int i;
    dev->cfg = *cfg;
    fg_decoder_init(&dev->decoder);
    dev->watchdog_us = (uint32_t)fg_watchdog_ms(cfg) * 1000UL;
    dev->last_command_us = 0;
    dev->errors_reported = 0;
    dev->seq = 0;
    dev->seq_applied = 0;
    dev->requested = 0;
    dev->motor = 0;
    dev->sensor = 0;
    dev->distance = -1.0f; /* no sample yet */
    dev->speed = 0.0f;
    dev->measured = 0.0f;
    dev->bound = 0.0f; /* the car boots at rest */
    dev->dt = 1.0f / (float)cfg->rate_hz;
    dev->held_peak = 0;
    for (i = 0; i < FG_GUARD_REACTION_PERIODS; i++) {
        dev->held[i] = 0;
    }
    dev->sampled = 0;
    dev->armed = 0;
    dev->enabled = 0;
    dev->fresh = 0;
    dev->latched = 0;
}

/* guard.py CarBounds.accel: the acceleration toward the wall at speed v >= 0 of a car of
 * mass (0: the largest of any plausible car). */
static float car_accel(const fg_car_bounds *car, float command, float v, float mass)
{
    float net = command - car->friction - car->viscous * v;
    if (mass <= 0.0f) {
        mass = net > 0.0f ? car->mass_min : car->mass_max;
    }
    return net / mass;
}

/* guard.py _count: the distance one IR count spans at d cm (Eq. (1): d^2 / (966 + d)). */
static float ir_count(float d)
{
    return d * d / (FG_IR_NUMERATOR + d);
}

/* guard.py CarBounds.top_speed, at least v (1e30: no viscous term, no top speed). */
static float car_top_speed(const fg_car_bounds *car, float command, float v)
{
    float net = command - car->friction, top = 0.0f;
    if (net > 0.0f) {
        top = car->viscous > 0.0f ? net / car->viscous : 1e30f;
    }
    return top > v ? top : v;
}

/* guard.py CarBounds.advance: the speed bound after holding command for t seconds. */
static float car_advance(const fg_car_bounds *car, float v, float command, float t)
{
    float a, top, slowed;
    v = v > 0.0f ? v : 0.0f;
    a = car_accel(car, command, v, 0.0f);
    if (a > 0.0f) { /* Euler, capped at the top speed: the acceleration only falls */
        top = car_top_speed(car, command, v);
        v = v + a * t;
        return v < top ? v : top;
    }
    /* implicit Euler: the exact decay is faster */
    slowed = (v + (command - car->friction) * t / car->mass_max) /
             (1.0f + car->viscous * t / car->mass_max);
    return slowed > 0.0f ? slowed : 0.0f;
}

/* guard.py stopping_point: where the car stops if it holds command for t, then brakes at full
 * reverse; the nearer for the lightest and the heaviest car (convex in the mass). */
static float stop_point(const fg_device *dev, float d, float speed, float t, float command)
{
    const fg_car_bounds *car = &dev->cfg.car;
    float force = (float)dev->cfg.command_limit + car->friction;
    float worst = d, mass, a, top, travel, v, stop;
    uint8_t i;
    speed = speed > 0.0f ? speed : 0.0f; /* a receding car counts as at rest */
    for (i = 0; i < 2; i++) {
        mass = i ? car->mass_max : car->mass_min;
        v = speed;
        a = car_accel(car, command, v, mass);
        travel = v * t;
        if (a > 0.0f) {
            top = car_top_speed(car, command, v);
            travel = travel + 0.5f * a * t * t;
            travel = travel < top * t ? travel : top * t;
            v = v + a * t;
            v = v < top ? v : top;
        }
        stop = d - travel - mass * v * v / (2.0f * force + car->viscous * v);
        worst = stop < worst ? stop : worst;
    }
    return worst;
}

/* The distance guard's prediction (fg_device.h; guard.py DistanceGuard._trips): would the
 * car, at the last sample's distance and approach speed (out of range: at the edge with the
 * speed bound, one period later), holding command (counts = units on the Altino) or what is
 * already on its way over the reaction time, fail to stop short of the limit braking then? */
static uint8_t guard_trips(const fg_device *dev, int16_t command)
{
    float dt = dev->dt;
    float t = (float)FG_GUARD_REACTION_PERIODS * dt;
    float stop;
    int i;
    if (!(dev->cfg.capabilities & FG_CAP_DISTANCE_LIMIT) || !dev->sampled) {
        return 0; /* no guard, or nothing to judge yet */
    }
    for (i = 0; i < FG_GUARD_REACTION_PERIODS; i++) {
        command = dev->held[i] > command ? dev->held[i] : command;
    }
    if (dev->distance < 0.0f) {
        stop = stop_point(dev, FG_GUARD_EDGE_CM, dev->bound, t + dt, (float)command);
    } else {
        stop = stop_point(dev, dev->distance, dev->speed, t, (float)command);
    }
    return (uint8_t)(stop <= dev->cfg.limit_cm);
}

/* Judge the last sample (guard.py DistanceGuard.update): latch LIMIT if the car would not
 * stop short of the limit braking now. */
static void guard_judge(fg_device *dev)
{
    if (guard_trips(dev, 0)) {
        dev->latched |= FG_STATUS_LIMIT;
    }
}

/* Feed one sample to the guard (guard.py DistanceGuard.update), the largest output held
 * since the last one being the newest of held[]. */
static void guard_update(fg_device *dev, int32_t readout)
{
    float distance = -1.0f; /* readout 0: out of range */
    float fast;
    int16_t command;
    int i;
    if (!(dev->cfg.capabilities & FG_CAP_DISTANCE_LIMIT)) {
        return; /* the servo: no float maths at 500 Hz */
    }
    command = dev->held_peak;
    for (i = 0; i + 1 < FG_GUARD_REACTION_PERIODS; i++) {
        dev->held[i] = dev->held[i + 1];
        command = dev->held[i] > command ? dev->held[i] : command;
    }
    dev->held[FG_GUARD_REACTION_PERIODS - 1] = dev->held_peak;
    dev->bound = car_advance(&dev->cfg.car, dev->bound, (float)command, dev->dt);
    if (readout > 0) {
        distance = FG_IR_NUMERATOR / ((float)readout + FG_IR_OFFSET);
    }
    if (distance < 0.0f || dev->distance < 0.0f) {
        dev->speed = dev->measured = dev->bound; /* no two readings: the fastest it can be */
    } else {
        /* the mean speed over the period; the car may be faster now by half a count and the
         * noise of each reading and half a period of acceleration (guard.py _now_at_most), not
         * above the bound unless the readings themselves are */
        dev->measured = (dev->distance - distance) / dev->dt;
        fast = dev->measured > 0.0f ? dev->measured : 0.0f;
        fast = car_accel(&dev->cfg.car, (float)command, fast, 0.0f) * dev->dt;
        fast = dev->measured + 0.5f * (fast > 0.0f ? fast : 0.0f) +
               (0.5f + dev->cfg.car.noise_counts) *
                   (ir_count(dev->distance) + ir_count(distance)) / dev->dt;
        fast = fast < dev->bound ? fast : dev->bound;
        dev->speed = fast > dev->measured ? fast : dev->measured;
    }
    dev->distance = distance;
    dev->sampled = 1;
    guard_judge(dev);
}

/* What the motor holds: the request if armed and enabled, else nothing; a forward one is
 * judged first, held from the last sample, and trips the guard if the car could not stop
 * short of the limit; once the guard has tripped (LIMIT), full reverse while the car
 * approaches, and never forward (guard.py DistanceGuard.command). The guard acts whether or
 * not the device is armed. */
static void update_motor(fg_device *dev)
{
    int16_t motor = (dev->armed && dev->enabled) ? dev->requested : 0;
    uint8_t guarded = (uint8_t)(dev->cfg.capabilities & FG_CAP_DISTANCE_LIMIT);
    if (guarded && !dev->sampled && motor > 0) {
        motor = 0; /* no distance known yet: forward is refused, nothing latched */
    }
    if (!(dev->latched & FG_STATUS_LIMIT) && motor > 0 && guard_trips(dev, motor)) {
        dev->latched |= FG_STATUS_LIMIT; /* the forward command is not let through */
    }
    if (dev->latched & FG_STATUS_LIMIT) {
        if (dev->distance >= 0.0f && dev->measured > FG_GUARD_STOPPED_SPEED) {
            motor = (int16_t)-dev->cfg.command_limit; /* the brake (never blind) */
        } else if (motor > 0) {
            motor = 0; /* backing away (negative) still passes */
        }
    }
    dev->motor = motor;
    if (motor > dev->held_peak) {
        dev->held_peak = motor; /* what the car may feel over this period */
    }
}

static int16_t clip(int16_t value, int16_t limit)
{
    if (value > limit) {
        return limit;
    }
    if (value < -limit) {
        return (int16_t)-limit;
    }
    return value;
}

uint8_t fg_device_receive(fg_device *dev, const fg_message *msg, uint32_t now_us)
{
    uint8_t act = 0;
    const fg_command *cmd = &msg->u.command;
    if (msg->type == FG_HELLO_REQUEST) {
        return FG_ACT_HELLO; /* any version: the host decides what to do with the answer */
    }
    if (msg->type != FG_COMMAND) {
        return 0; /* Place (emulator only) and device-to-host messages: ignored */
    }
    dev->last_command_us = now_us;
    dev->fresh = 1;
    dev->seq_applied = cmd->seq;
    if (cmd->flags & FG_FLAG_REARM) {
        dev->latched = 0;
        dev->armed = 1;
        guard_judge(dev); /* the latest sample still trips it: LIMIT comes straight back */
    }
    if (cmd->flags & FG_FLAG_ESTOP) {
        dev->armed = 0; /* after REARM: an e-stop always wins */
    }
    if (cmd->flags & FG_FLAG_ZERO_POSITION) {
        act |= FG_ACT_ZERO;
    }
    dev->enabled = (cmd->flags & FG_FLAG_ENABLE) ? 1u : 0u;
    dev->requested = clip(cmd->command, dev->cfg.command_limit);
    update_motor(dev);
    return (uint8_t)(act | FG_ACT_MOTOR);
}

uint8_t fg_device_rx(fg_device *dev, uint8_t byte, uint32_t now_us)
{
    fg_message msg;
    if (fg_decoder_push(&dev->decoder, byte, &msg)) {
        return fg_device_receive(dev, &msg, now_us);
    }
    return 0;
}

size_t fg_device_tick(fg_device *dev, uint32_t now_us, int32_t sensor, int16_t aux,
                      uint8_t hw_status, uint8_t *frame, fg_state *state)
{
    fg_message msg;
    fg_state *s = &msg.u.state;
    uint8_t status = (uint8_t)(hw_status & (FG_STATUS_AMP_FAULT | FG_STATUS_STALL |
                                            FG_STATUS_STALL_ERROR));
    /* 1. faults: an amplifier fault or stall error disarms (re-arm after it clears) */
    if (status & (FG_STATUS_AMP_FAULT | FG_STATUS_STALL_ERROR)) {
        dev->armed = 0;
    }
    /* 2. watchdog: armed, and no Command for watchdog_us */
    if (dev->armed && (uint32_t)(now_us - dev->last_command_us) >= dev->watchdog_us) {
        dev->latched |= FG_STATUS_WATCHDOG;
        dev->armed = 0;
    }
    /* 3. the output held over the period ending now (the guard as it judged the last sample;
     *    the newest command, checked against it on arrival and again here) */
    if (dev->armed && dev->enabled && !dev->fresh) {
        status |= FG_STATUS_COMMAND_LATE;
    }
    update_motor(dev);
    s->applied = dev->motor;
    /* 4. the new sample; the guard's output, the held command checked against the new
     *    sample, is the motor's for the next period */
    dev->sensor = sensor;
    guard_update(dev, sensor);
    dev->held_peak = (int16_t)-dev->cfg.command_limit; /* the next period starts */
    update_motor(dev);
    /* 5. the State */
    if (dev->decoder.errors != dev->errors_reported) {
        status |= FG_STATUS_CRC_ERROR;
        dev->errors_reported = dev->decoder.errors;
    }
    if (!dev->armed || !dev->enabled) {
        status |= FG_STATUS_DISABLED;
    }
    msg.type = FG_STATE;
    s->status = (uint8_t)(status | dev->latched);
    s->seq = ++dev->seq; /* the first State is 1 */
    s->tick_us = now_us;
    s->seq_applied = dev->seq_applied;
    s->sensor = sensor;
    s->aux = aux;
    dev->fresh = 0;
    if (state != 0) {
        *state = *s;
    }
    return fg_encode(&msg, frame);
}

size_t fg_device_hello(const fg_device *dev, uint8_t *frame)
{
    fg_message msg;
    msg.type = FG_HELLO;
    msg.u.hello.version = FG_PROTOCOL_VERSION;
    msg.u.hello.kind = dev->cfg.kind;
    msg.u.hello.capabilities = dev->cfg.capabilities;
    msg.u.hello.rate_hz = dev->cfg.rate_hz;
    msg.u.hello.counts_per_rev = dev->cfg.counts_per_rev;
    msg.u.hello.command_scale = dev->cfg.command_scale;
    msg.u.hello.command_limit = dev->cfg.command_limit;
    msg.u.hello.watchdog_ms = (uint16_t)(dev->watchdog_us / 1000UL);
    msg.u.hello.firmware = dev->cfg.firmware;
    return fg_encode(&msg, frame);
}

void fg_device_set_car(fg_device *dev, const fg_car_bounds *car)
{
    dev->cfg.car = *car;
}

int16_t fg_device_motor(const fg_device *dev)
{
    return dev->motor;
}

uint8_t fg_device_amp_enabled(const fg_device *dev)
{
    return (uint8_t)((dev->armed && dev->enabled) || dev->motor != 0);
}

void fg_device_estop(fg_device *dev)
{
    dev->armed = 0;
    update_motor(dev);
}
