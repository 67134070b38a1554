// A stub of the few Arduino functions the sketch uses, so that `make sketch-check` compiles voxhap_arm.ino as C++
// against the library on a machine without an Arduino toolchain (declarations only: nothing is linked or run).
#include <stdint.h>
#include <string.h>
#include <stddef.h>
#define LOW 0
#define HIGH 1
#define OUTPUT 1
#define INPUT_PULLUP 2
uint32_t micros(void);
void pinMode(int, int);
void digitalWrite(int, int);
int digitalRead(int);
void analogWrite(int, int);
struct SerialStub { void begin(long); int available(); int read(); size_t write(const uint8_t *, size_t); };
extern SerialStub Serial;
