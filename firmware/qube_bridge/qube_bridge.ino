/*
 * qube_bridge.ino - QUBE-Servo 2 bridge: the frictiongym protocol on USB serial, SPI to the QUBE.
 *
 * An Arduino (Uno, Mega, or any board with SPI and micros()) sits between the host and a
 * QUBE-Servo 2 with the embedded SPI interface panel. Every 2 ms (500 Hz) it runs one SPI
 * transaction (motor command out; encoder, status and current in) and sends one State frame;
 * Command frames from the host set the motor at once (one more SPI transaction), so a command
 * is held from its arrival to the end of the period and echoed by that period's State.
 * Safety (firmware/common/fg_device.c): the motor is off until the host re-arms, clipped to
 * +-10 V, and zeroed with the amplifier disabled when commands stop for 100 ms.
 *
 * Build: arduino-cli compile --fqbn arduino:avr:uno --library firmware/common \
 *            firmware/qube_bridge            (see firmware/README.md; wiring there too)
 * Host:  gym.make("frictiongym/RotaryServo-v0", backend="serial:///dev/ttyACM0?baud=1000000")
 *
 * Sources: SPI settings, byte layout, 625/15 V-to-PWM scaling, bit-15 amplifier enable, status
 * bits, current scaling and module ID are those of Quanser's QUBE-Servo 2 Arduino library and
 * examples; this file is our own code.
 */
#include <SPI.h>
#include <fg_device.h>

/* ---- configuration ------------------------------------------------------------------------ */

/* Host link: exact on 16 MHz AVRs, and a 21-byte State at 500 Hz uses 11 % of it. Boards with
 * native USB ignore the number. */
static const uint32_t HOST_BAUD = 1000000UL;
/* QUBE SPI: 1 MHz, MSB first, mode 2 (CPOL 1, CPHA 0); slave select on pin 10 [Q5]. */
static const uint32_t QUBE_SPI_HZ = 1000000UL;
static const uint8_t QUBE_SS_PIN = 10;
/* Module ID the QUBE-Servo 2 reports in the first two MISO bytes [Q5]. */
static const uint16_t QUBE_MODULE_ID = 777;
/* +1 if a positive motor command increases encoder 0's count on your unit, else -1: the host
 * expects a positive command to increase the angle (check it once with a small command). */
static const int8_t ENCODER_SIGN = 1;
/* LED intensities, 0..999 [Q5]. */
static const uint16_t LED_ON = 400;

/* Write-mask bits of MOSI byte 2 [Q5][Q6]. */
enum {
    MASK_MOTOR = 0x01,
    MASK_AMP = 0x02,
    MASK_LEDS = 0x1C,
    MASK_ENCODER0 = 0x20,
    MASK_ENCODER1 = 0x40
};

/* ---- QUBE I/O ----------------------------------------------------------------------------- */

struct QubeSample {
    uint16_t module_id;
    int32_t encoder0;   /* arm/disk encoder, counts (24-bit, sign-extended) */
    uint8_t status;     /* bit 0 amplifier fault, 1 stall detected, 2 stall error */
    int16_t current_ma; /* motor current */
};

static fg_device dev;
static uint8_t frame[FG_FRAME_BUFFER];
static uint32_t period_us;
static uint32_t next_tick_us;
static QubeSample last;

/* mV to the QUBE's PWM command, rounded: Quanser's pwm = V * 625 / 15 [Q5]. */
static int16_t mv_to_pwm(int16_t mv)
{
    int32_t num = (int32_t)mv * 625L;
    return (int16_t)((num + (num >= 0 ? 7500L : -7500L)) / 15000L);
}

static int32_t sign_extend_24(uint32_t v)
{
    return (v & 0x800000UL) ? (int32_t)(v | 0xFF000000UL) : (int32_t)v;
}

/* One 17-byte full-duplex transaction: write the motor (and LEDs, optionally zero the
 * encoders), read the encoders, status and current. */
static QubeSample qube_transfer(int16_t mv, bool amp, uint8_t extra_mask, uint16_t rgb[3])
{
    uint8_t tx[17] = {0}, rx[17];
    uint16_t motor = (uint16_t)((uint16_t)mv_to_pwm(mv) & 0x7FFFu) | (amp ? 0x8000u : 0u);
    tx[0] = 1; /* normal mode */
    tx[2] = (uint8_t)(MASK_MOTOR | MASK_AMP | MASK_LEDS | extra_mask);
    for (uint8_t i = 0; i < 3; i++) {
        tx[3 + 2 * i] = (uint8_t)(rgb[i] >> 8);
        tx[4 + 2 * i] = (uint8_t)(rgb[i] & 0xFF);
    }
    /* bytes 9..14: encoder presets, 0 (used only with MASK_ENCODER0/1) */
    tx[15] = (uint8_t)(motor >> 8);
    tx[16] = (uint8_t)(motor & 0xFF);

    SPI.beginTransaction(SPISettings(QUBE_SPI_HZ, MSBFIRST, SPI_MODE2));
    digitalWrite(QUBE_SS_PIN, LOW);
    for (uint8_t i = 0; i < 17; i++) {
        rx[i] = SPI.transfer(tx[i]);
    }
    digitalWrite(QUBE_SS_PIN, HIGH);
    SPI.endTransaction();

    QubeSample s;
    s.module_id = (uint16_t)((uint16_t)rx[0] << 8 | rx[1]);
    s.encoder0 = sign_extend_24((uint32_t)rx[2] << 16 | (uint32_t)rx[3] << 8 | rx[4]);
    s.status = (uint8_t)(rx[11] & 0x07);
    /* Quanser: I = 3.3 / (4 * 4095) * (raw / 2 - 4095) A [Q5] */
    int32_t raw = (int32_t)((uint16_t)rx[12] << 8 | rx[13]);
    s.current_ma = (int16_t)((raw - 8190L) * 3300L / 32760L);
    return s;
}

/* Hardware status bits for the state machine: no QUBE answering is an amplifier fault. */
static uint8_t hw_status(const QubeSample &s)
{
    return s.module_id == QUBE_MODULE_ID ? s.status : (uint8_t)FG_STATUS_AMP_FAULT;
}

/* Write the motor as the state machine holds it; LED green = driving, red = a latched fault,
 * blue = idle. */
static void apply_motor(uint8_t extra_mask)
{
    uint16_t rgb[3] = {0, 0, 0};
    if (fg_device_amp_enabled(&dev)) {
        rgb[1] = LED_ON;
    } else if (dev.latched || (hw_status(last) & (FG_STATUS_AMP_FAULT | FG_STATUS_STALL_ERROR))) {
        rgb[0] = LED_ON;
    } else {
        rgb[2] = LED_ON;
    }
    last = qube_transfer(fg_device_motor(&dev), fg_device_amp_enabled(&dev), extra_mask, rgb);
}

/* ---- sketch ------------------------------------------------------------------------------- */

void setup()
{
    fg_device_config cfg = fg_config_rotary();
    fg_device_init(&dev, &cfg);
    period_us = 1000000UL / cfg.rate_hz;

    pinMode(QUBE_SS_PIN, OUTPUT);
    digitalWrite(QUBE_SS_PIN, HIGH);
    SPI.begin();
    /* boot: amplifier disabled (this also clears a stall error [Q5]), both encoders zeroed */
    apply_motor(MASK_ENCODER0 | MASK_ENCODER1);

    Serial.begin(HOST_BAUD);
    next_tick_us = micros() + period_us;
}

void loop()
{
    while (Serial.available() > 0) {
        uint8_t act = fg_device_rx(&dev, (uint8_t)Serial.read(), micros());
        if (act & FG_ACT_HELLO) {
            Serial.write(frame, fg_device_hello(&dev, frame));
        }
        if (act & (FG_ACT_MOTOR | FG_ACT_ZERO)) { /* the command holds from its arrival */
            apply_motor((act & FG_ACT_ZERO) ? MASK_ENCODER0 : 0);
        }
    }

    uint32_t now = micros();
    if ((int32_t)(now - next_tick_us) < 0) {
        return;
    }
    next_tick_us += period_us;
    if ((int32_t)(now - next_tick_us) >= 0) { /* overrun: skip missed ticks, never burst */
        next_tick_us = now + period_us;
    }
    int16_t before = fg_device_motor(&dev);
    uint8_t amp_before = fg_device_amp_enabled(&dev);
    apply_motor(0); /* sample (and refresh the command) */
    size_t n = fg_device_tick(&dev, now, ENCODER_SIGN * last.encoder0, last.current_ma,
                              hw_status(last), frame, NULL);
    if (fg_device_motor(&dev) != before || fg_device_amp_enabled(&dev) != amp_before) {
        apply_motor(0); /* the watchdog or a fault zeroed the motor: write it now */
    }
    Serial.write(frame, n);
}
