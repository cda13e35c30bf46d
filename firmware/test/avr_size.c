/*
 * avr_size.c - a program that uses every function of firmware/common, to measure its flash.
 *
 * tests/test_firmware.py links it for the AVR (avr-gcc -Os, --gc-sections) and prints the
 * size that firmware/README.md ("Code size") reports: the common code, the C runtime and the
 * libgcc routines it pulls in (the distance guard's binary32 maths), without any sketch.
 * The volatile inputs keep the compiler from folding anything away.
 */
#include "../common/fg_device.h"

static volatile uint8_t input;
static volatile uint8_t sink8;
static volatile int16_t sink16;
static fg_device dev;
static uint8_t frame[FG_FRAME_BUFFER];

int main(void)
{
    fg_device_config cfg = input ? fg_config_rotary() : fg_config_altino();
    fg_device_init(&dev, &cfg);
    for (;;) {
        uint8_t act = fg_device_rx(&dev, input, 1000UL);
        if (act & FG_ACT_HELLO) {
            sink8 = (uint8_t)fg_device_hello(&dev, frame);
        }
        sink8 = (uint8_t)fg_device_tick(&dev, 2000UL, input, 0, input, frame, 0);
        sink16 = fg_device_motor(&dev);
        sink8 = fg_device_amp_enabled(&dev);
        if (input == 7u) {
            fg_device_estop(&dev);
        }
    }
}
