/* The Arduino Mega 2560's booth pins: the one table the board layer (board_mega2560.c) and the
 * wiring diagram (lab/wiring.py -> docs/booth-wiring.svg, regenerated and compared by the
 * tests) are made from. Change a pin here and both follow.
 *
 * BOOTH_LED_PINS: X(channel, AVR port, bit, Arduino pin, timer, compare unit) -- the LED channels in
 * NAMES= order, each a 16-bit timer's output compare pin (fast PWM, TOP = ICRn).
 * BOOTH_TRIGGER_OUT: X(AVR port, bit, Arduino pin) -- to the camera's trigger input (booth master).
 * BOOTH_EXPOSURE_IN: X(AVR port, bit, Arduino pin, interrupt) -- from the camera's ExposureActive
 * output (camera master), internal pull-up on. */
#ifndef PINS_MEGA2560_H
#define PINS_MEGA2560_H

#define BOOTH_LED_PINS(X)                                                                        \
    X(0, E, 3, 5, 3, A)                                                                          \
    X(1, E, 4, 2, 3, B)                                                                          \
    X(2, E, 5, 3, 3, C)                                                                          \
    X(3, H, 3, 6, 4, A)                                                                          \
    X(4, H, 4, 7, 4, B)                                                                          \
    X(5, H, 5, 8, 4, C)                                                                          \
    X(6, L, 3, 46, 5, A)

#define BOOTH_TRIGGER_OUT(X) X(A, 0, 22)
#define BOOTH_EXPOSURE_IN(X) X(D, 0, 21, INT0)

#endif
