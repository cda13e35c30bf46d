/*
 * altino.ino - Altino car: the frictiongym protocol to the host, the vendor's frames to the car.
 *
 * Runs on the Altino's user MCU in place of a sketch built on the vendor's Altino.h. It talks
 * to the car's base controller over `Serial` at 115200 with the vendor's 28-byte command frames
 * and 31-byte sensor replies (the vendor's PC and Arduino libraries), and to the host over
 * a second serial port with our protocol. Every 50 ms (20 Hz) it sends one State whose sensor
 * is the front-centre IR readout (0..800, grows toward the wall; d = 966 / (x + 45) cm).
 * Both wheels get the host's command (motor units, +-1000; positive drives forward, toward
 * the wall in front of the IR sensor); a Command sets the wheels at once.
 * Safety (firmware/common/fg_device.c): the motor is off until the host re-arms; commands stop
 * -> zero within 150 ms; the distance guard (frictiongym/hardware/guard.py's rule) predicts
 * from the IR readout and its change per tick where the car would stop, and once that is
 * within 1.5 cm of the wall it brakes at full reverse while the car approaches (even after an
 * e-stop or a watchdog trip) and refuses forward commands until the host re-arms; a car base
 * that stops answering for 150 ms is reported as AMP_FAULT, which disarms.
 *
 * Build: arduino-cli compile --fqbn <your board> --library firmware/common firmware/altino
 * Host:  gym.make("frictiongym/AltinoDistance-v0", backend="serial:///dev/ttyUSB0?baud=115200")
 *
 * The frame layout, checksums and sign-magnitude motor encoding follow the vendor library
 * (frictiongym/hardware/altino_frames.py has the same codec); this file is our own code.
 * Unverified on a car: the base's answer to every frame and the steering-centre value (see
 * firmware/README.md).
 */
#include <fg_device.h>

/* ---- configuration ------------------------------------------------------------------------ */

/* The car's base controller: hardware Serial at 115200 8N1 [A1][A2]. */
#define CAR Serial
static const uint32_t CAR_BAUD = 115200UL;
/* The host: a second UART (USB-serial adapter or a Bluetooth SPP module). A 21-byte State and
 * a 9-byte Command at 20 Hz need 600 B/s: even 9600 baud carries them. On a board with one
 * UART use SoftwareSerial for the host (an HC-06 module on pins 5/6 at 9600 [A4]). */
#define HOST Serial1
static const uint32_t HOST_BAUD = 115200UL;
/* The vendor library waits 10 ms after every frame [A2]: keep frames at least this far apart,
 * and ask for the sensors this long before the tick so the reading is fresh at the tick. */
static const uint32_t CAR_FRAME_GAP_US = 10000UL;
static const uint32_t SENSOR_LEAD_US = 10000UL;
/* Index of the front-centre IR sensor (IR[1], as in the vendor's Arduino examples). */
static const uint8_t IR_FRONT = 1;
/* A car that has not answered for this long reports AMP_FAULT (which disarms): the distance
 * guard must never drive on a stale reading (a repeated readout is a car at rest to it, so a
 * brake stops). Three periods, as the watchdog. */
static const uint32_t REPLY_TIMEOUT_US = 150000UL;

/* ---- vendor frames ------------------------------------------------------------------------ */

enum { CMD_LEN = 28, REPLY_LEN = 31, STX = 0x02, ETX = 0x03, SENSOR_GROUP_1 = 1 };

static fg_device dev;
static uint8_t frame[FG_FRAME_BUFFER];
static uint8_t reply[REPLY_LEN];
static uint8_t reply_len;
static int32_t ir_readout;       /* newest front IR readout from a good reply */
static uint32_t last_reply_us;   /* when that reply arrived */
static uint32_t period_us, next_tick_us, last_frame_us;
static bool frame_pending, sensor_requested;

/* Sign-magnitude, big-endian: negative values are sent as 32768 + |v| [A1]. */
static void put_wheel(uint8_t *at, int16_t value)
{
    uint16_t v = value < 0 ? (uint16_t)(32768u + (uint16_t)(-value)) : (uint16_t)value;
    at[0] = value == 0 ? 255 : 0; /* mode byte: 255 = stop (brake), 0 = drive [A1] */
    at[1] = (uint8_t)(v >> 8);
    at[2] = (uint8_t)(v & 0xFF);
}

/* One command frame: both wheels at `motor`, wheels straight, sensor group 1 requested. */
static void send_car_frame(int16_t motor)
{
    uint8_t tx[CMD_LEN] = {0};
    tx[0] = STX;
    tx[1] = CMD_LEN;
    tx[3] = 1;
    tx[4] = SENSOR_GROUP_1; /* ask for IR/torque/temperature/CDS: a 31-byte reply */
    tx[5] = 0;              /* steering value 0 with byte 24 = 1: Steering2(0, 0), centre */
    put_wheel(tx + 6, motor);  /* right wheel: bytes 6..8 */
    put_wheel(tx + 9, motor);  /* left wheel: bytes 9..11 */
    tx[21] = 0x01;             /* set whenever sensors are requested [A1] */
    tx[24] = 1;
    tx[27] = ETX;
    uint16_t sum = tx[1];
    for (uint8_t i = 3; i < CMD_LEN; i++) {
        sum += tx[i];
    }
    tx[2] = (uint8_t)(sum & 0xFF); /* (byte 1 + bytes 3..27) mod 256 [A1] */
    CAR.write(tx, CMD_LEN);
    last_frame_us = micros();
    frame_pending = false;
}

/* Collect 31-byte replies byte by byte; keep the front IR of every good group-1 reply. */
static void car_rx(uint8_t byte)
{
    if (reply_len == 0 && byte != STX) {
        return; /* hunt for the start of a reply */
    }
    reply[reply_len++] = byte;
    if (reply_len == 2 && byte != REPLY_LEN) {
        reply_len = 0;
        return;
    }
    if (reply_len < REPLY_LEN) {
        return;
    }
    reply_len = 0;
    uint16_t sum = 0;
    for (uint8_t i = 0; i < REPLY_LEN; i++) {
        sum += i == 2 ? 0 : reply[i]; /* every byte but the checksum itself [A1] */
    }
    if (reply[REPLY_LEN - 1] == ETX && (uint8_t)sum == reply[2] && reply[4] == SENSOR_GROUP_1) {
        const uint8_t *ir = reply + 7 + 2 * IR_FRONT; /* IR1..IR6 at bytes 7..18, big-endian */
        ir_readout = (int32_t)((uint16_t)ir[0] << 8 | ir[1]);
        last_reply_us = micros();
    }
}

/* ---- sketch ------------------------------------------------------------------------------- */

void setup()
{
    fg_device_config cfg = fg_config_altino();
    /* The distance guard assumes any mass 1.1-5.5 and the paper's least friction (cfg.car); on
     * a surface with less friction set cfg.car.friction / .viscous here (or -DFG_GUARD_*). */
    fg_device_init(&dev, &cfg);
    period_us = 1000000UL / cfg.rate_hz;
    CAR.begin(CAR_BAUD);
    HOST.begin(HOST_BAUD);
    send_car_frame(0); /* stopped at boot */
    next_tick_us = micros() + period_us;
}

void loop()
{
    while (CAR.available() > 0) {
        car_rx((uint8_t)CAR.read());
    }
    while (HOST.available() > 0) {
        uint8_t act = fg_device_rx(&dev, (uint8_t)HOST.read(), micros());
        if (act & FG_ACT_HELLO) {
            HOST.write(frame, fg_device_hello(&dev, frame));
        }
        if (act & FG_ACT_MOTOR) {
            frame_pending = true; /* sent as soon as the car's frame gap allows */
        }
    }

    uint32_t now = micros();
    if (!sensor_requested && (int32_t)(now - (next_tick_us - SENSOR_LEAD_US)) >= 0) {
        frame_pending = true; /* the sensor poll (and keep-alive) before the tick */
        sensor_requested = true;
    }
    if (frame_pending && (uint32_t)(now - last_frame_us) >= CAR_FRAME_GAP_US) {
        send_car_frame(fg_device_motor(&dev));
    }
    if ((int32_t)(now - next_tick_us) < 0) {
        return;
    }
    next_tick_us += period_us;
    if ((int32_t)(now - next_tick_us) >= 0) { /* overrun: skip missed ticks, never burst */
        next_tick_us = now + period_us;
    }
    sensor_requested = false;
    int16_t before = fg_device_motor(&dev);
    uint8_t hw = (uint32_t)(now - last_reply_us) > REPLY_TIMEOUT_US ? FG_STATUS_AMP_FAULT : 0;
    size_t n = fg_device_tick(&dev, now, ir_readout, 0, hw, frame, NULL);
    if (fg_device_motor(&dev) != before) {
        frame_pending = true; /* watchdog: stop the wheels; distance guard: brake or stop */
    }
    HOST.write(frame, n);
}
