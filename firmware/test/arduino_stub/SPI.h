/*
 * SPI.h (host stub) - see Arduino.h in this folder.
 */
#ifndef FG_SPI_STUB_H
#define FG_SPI_STUB_H

#include "Arduino.h"

#define MSBFIRST 1
#define SPI_MODE2 0x08

struct SPISettings {
    SPISettings(uint32_t clock_hz, uint8_t bit_order, uint8_t data_mode)
        : clock(clock_hz), order(bit_order), mode(data_mode) {}
    uint32_t clock;
    uint8_t order, mode;
};

class SPIClass {
public:
    void begin();
    void beginTransaction(SPISettings settings);
    uint8_t transfer(uint8_t byte);
    void endTransaction();
};

extern SPIClass SPI;

#endif
