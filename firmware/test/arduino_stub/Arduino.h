/*
 * Arduino.h (host stub) - the part of the Arduino API the reference sketches use, so that
 * tests/test_firmware.py can compile and run them on the host (firmware/test/sketch_sim.cpp
 * implements it). Not an Arduino core: no timers, no interrupts, no real I/O.
 */
#ifndef FG_ARDUINO_STUB_H
#define FG_ARDUINO_STUB_H

#include <stddef.h>
#include <stdint.h>

#define INPUT 0
#define OUTPUT 1
#define LOW 0
#define HIGH 1

unsigned long micros(void);
void pinMode(uint8_t pin, uint8_t mode);
void digitalWrite(uint8_t pin, uint8_t value);

class HardwareSerial {
public:
    void begin(unsigned long baud);
    int available();
    int read();
    size_t write(uint8_t byte);
    size_t write(const uint8_t *data, size_t len);

    /* test side */
    unsigned long baud = 0;
    uint8_t rx[8192];
    size_t rx_head = 0, rx_tail = 0;
    uint8_t tx[8192];
    size_t tx_len = 0;
};

extern HardwareSerial Serial;
extern HardwareSerial Serial1;

#endif
