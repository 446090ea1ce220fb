/*
 * A straight transcription of the C program in ART's calibration report (section 1),
 * with its typos fixed as the report means them: RateConvFactor is RATE_SCALE_FACTOR,
 * variables declared once, semicolons added. GetDataGyro() reads the next sample of
 * an input file instead of the serial port. Used by the tests as the reference and by
 * bench/ as the C baseline.
 *
 * Usage: art_reference PARAMS IN OUT
 *   PARAMS: text "rate_scale_factor rows columns c00 c01 ... bias_samples"
 *   IN:     int32 pairs (RawGyroRate, RawGyroTemp), native byte order
 *   OUT:    float32 pairs (comp, CompRate) per sample after the static bias samples
 * Prints the seconds spent in the compensation loop.
 */
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <time.h>

#define TEMP_SCALE_FACTOR 0.05
#define MAX_ROWS 10
#define MAX_COLUMNS 10

static float RATE_SCALE_FACTOR;
static int ROWS, COLUMNS, BIAS_SAMPLES;
static float coef[MAX_ROWS][MAX_COLUMNS];

static const int *samples;
static long n_samples, next_sample;

float StaticBiasDrift;
float CalcStaticBiasDrift;

void GetDataGyro(float *RawGyroRate, float *RawGyroTemp)
{
    *RawGyroRate = (float)samples[2 * next_sample];
    *RawGyroTemp = (float)samples[2 * next_sample + 1];
    next_sample++;
}

float CompFunction(float GyroRate, float GyroTemp)
{
    float sumT[10];
    float Aux;
    int i, j;
    float comp = 0;
    for (i = 0; i < COLUMNS; i++)
    {
        sumT[i] = 0;
        for (j = 0; j < ROWS; j++)
        {
            Aux = (ROWS - j - 1) ? pow(GyroTemp, ROWS - j - 1) : 1;
            sumT[i] += Aux * coef[j][i];
        }
    }
    for (i = 0; i < COLUMNS; i++)
    {
        Aux = (COLUMNS - i - 1) ? pow(GyroRate, COLUMNS - i - 1) : 1;
        comp += Aux * sumT[i];
    }
    return comp;
}

void StaticBias(void)
{
    float RawGyroRate;
    float GyroRate;
    float GyroTemp;
    float RawGyroTemp;

    float SumB = 0;
    float SumC = 0;
    for (int i = 0; i < BIAS_SAMPLES; i++)
    {
        GetDataGyro(&RawGyroRate, &RawGyroTemp);
        SumB += RawGyroRate;
        GyroRate = RATE_SCALE_FACTOR * RawGyroRate;
        GyroTemp = TEMP_SCALE_FACTOR * RawGyroTemp;
        SumC += CompFunction(GyroRate, GyroTemp);
    }
    StaticBiasDrift = SumB * RATE_SCALE_FACTOR / BIAS_SAMPLES;
    CalcStaticBiasDrift = SumC / BIAS_SAMPLES;
}

int main(int argc, char **argv)
{
    if (argc != 4) {
        fprintf(stderr, "usage: %s PARAMS IN OUT\n", argv[0]);
        return 2;
    }
    FILE *p = fopen(argv[1], "r");
    if (!p || fscanf(p, "%f %d %d", &RATE_SCALE_FACTOR, &ROWS, &COLUMNS) != 3
        || ROWS < 1 || ROWS > MAX_ROWS || COLUMNS < 1 || COLUMNS > MAX_COLUMNS) {
        fprintf(stderr, "%s: bad parameters\n", argv[1]);
        return 2;
    }
    for (int j = 0; j < ROWS; j++)
        for (int i = 0; i < COLUMNS; i++)
            if (fscanf(p, "%f", &coef[j][i]) != 1) {
                fprintf(stderr, "%s: too few coefficients\n", argv[1]);
                return 2;
            }
    if (fscanf(p, "%d", &BIAS_SAMPLES) != 1 || BIAS_SAMPLES < 1) {
        fprintf(stderr, "%s: bad bias_samples\n", argv[1]);
        return 2;
    }
    fclose(p);

    FILE *in = fopen(argv[2], "rb");
    if (!in) { perror(argv[2]); return 2; }
    fseek(in, 0, SEEK_END);
    n_samples = ftell(in) / (2 * sizeof(int));
    fseek(in, 0, SEEK_SET);
    int *buf = malloc(n_samples * 2 * sizeof(int));
    if (n_samples <= BIAS_SAMPLES || fread(buf, 2 * sizeof(int), n_samples, in) != (size_t)n_samples) {
        fprintf(stderr, "%s: too few samples\n", argv[2]);
        return 2;
    }
    fclose(in);
    samples = buf;
    long n_out = n_samples - BIAS_SAMPLES;
    float *out = malloc(n_out * 2 * sizeof(float));

    struct timespec t0, t1;
    clock_gettime(CLOCK_MONOTONIC, &t0);
    StaticBias();
    for (long k = 0; k < n_out; k++)
    {
        float RawGyroRate, RawGyroTemp, GyroRate, GyroTemp, CompRate, comp;
        GetDataGyro(&RawGyroRate, &RawGyroTemp);
        GyroRate = RATE_SCALE_FACTOR * RawGyroRate;
        GyroTemp = TEMP_SCALE_FACTOR * RawGyroTemp;
        comp = CompFunction(GyroRate, GyroTemp);
        CompRate = GyroRate - StaticBiasDrift - comp + CalcStaticBiasDrift;
        out[2 * k] = comp;
        out[2 * k + 1] = CompRate;
    }
    clock_gettime(CLOCK_MONOTONIC, &t1);

    FILE *o = fopen(argv[3], "wb");
    if (!o || fwrite(out, 2 * sizeof(float), n_out, o) != (size_t)n_out) {
        perror(argv[3]);
        return 2;
    }
    fclose(o);
    printf("%.9f\n", (t1.tv_sec - t0.tv_sec) + 1e-9 * (t1.tv_nsec - t0.tv_nsec));
    free(buf);
    free(out);
    return 0;
}
