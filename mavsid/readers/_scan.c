/* The loops of mavsid's readers that numpy does in several passes (or Python one step at a
 * time), compiled. Optional:
 * where the package is built without a C compiler the readers use their numpy code instead
 * (same results; tests compare the two).
 *
 * The DataFlash header scan: every 0xA3 0x95 byte pair of a buffer with the byte after it
 * (its message type), as mavsid.readers.dataflash._find_headers_numpy finds them, in one
 * pass over the bytes instead of five over masks.
 *
 * pairs(data, start, stop, offsets, types) -> (count, reached)
 *   data     a readable buffer of bytes (n of them)
 *   start    the first offset looked at; stop the one after the last (stop <= n - 2: a pair
 *            needs its type byte)
 *   offsets  a writable int32 or int64 buffer the pairs' offsets are written to, in order
 *   types    a writable byte buffer their type bytes are written to
 *   count    pairs written (at most the shorter output's length)
 *   reached  stop when the range is done; else the offset of the first pair that found no
 *            room (call again from there with more room)
 * `vectorised` says whether the SSE2 loop was compiled: without it (ARM...) the byte loop is
 * slower than numpy's vectorised compares (51 against 34 ms on 104 MB here), and the reader
 * keeps numpy's scan.
 */
#define PY_SSIZE_T_CLEAN
#include <Python.h>
#include <stdint.h>
#include <string.h>

#if defined(__SSE2__) || defined(_M_X64)
#include <emmintrin.h>
#define MAVSID_SSE2 1
#endif

#define HEAD1 0xA3
#define HEAD2 0x95

static Py_ssize_t scan(const uint8_t *a, Py_ssize_t i, Py_ssize_t stop, void *offsets, int wide,
                       uint8_t *types, Py_ssize_t cap, Py_ssize_t *count)
{
    Py_ssize_t c = 0;
#define PUT(at)                                                                               \
    do {                                                                                      \
        if (c == cap) {                                                                       \
            *count = c;                                                                       \
            return (at);                                                                      \
        }                                                                                     \
        if (wide)                                                                             \
            ((int64_t *)offsets)[c] = (int64_t)(at);                                          \
        else                                                                                  \
            ((int32_t *)offsets)[c] = (int32_t)(at);                                          \
        types[c++] = a[(at) + 2];                                                             \
    } while (0)
#ifdef MAVSID_SSE2
    const __m128i h1 = _mm_set1_epi8((char)HEAD1), h2 = _mm_set1_epi8((char)HEAD2);
    /* 16 offsets a step; the second load reads a[i + 16] <= a[stop] < a[n - 1] */
    for (; i + 16 <= stop; i += 16) {
        __m128i x = _mm_loadu_si128((const __m128i *)(a + i));
        __m128i y = _mm_loadu_si128((const __m128i *)(a + i + 1));
        unsigned m = (unsigned)_mm_movemask_epi8(
            _mm_and_si128(_mm_cmpeq_epi8(x, h1), _mm_cmpeq_epi8(y, h2)));
        while (m) {
#if defined(__GNUC__) || defined(__clang__)
            int b = __builtin_ctz(m);
#else
            int b = 0;
            while (!((m >> b) & 1u))
                b++;
#endif
            m &= m - 1;
            PUT(i + b);
        }
    }
#endif
    for (; i < stop; i++) {
        if (a[i] == HEAD1 && a[i + 1] == HEAD2)
            PUT(i);
    }
#undef PUT
    *count = c;
    return stop;
}

/* Take a view of each object (the flags of each); on failure, give back those taken. */
static int get_buffers(PyObject *const *objs, Py_buffer *views, const int *flags, int n)
{
    for (int k = 0; k < n; k++) {
        if (PyObject_GetBuffer(objs[k], &views[k], flags[k]) < 0) {
            while (k--)
                PyBuffer_Release(&views[k]);
            return -1;
        }
    }
    return 0;
}

static void release_buffers(Py_buffer *views, int n)
{
    while (n--)
        PyBuffer_Release(&views[n]);
}

static PyObject *pairs(PyObject *self, PyObject *args)
{
    (void)self;
    PyObject *objs[3];
    Py_ssize_t start, stop;
    if (!PyArg_ParseTuple(args, "OnnOO:pairs", &objs[0], &start, &stop, &objs[1], &objs[2]))
        return NULL;
    Py_buffer views[3];
    const int flags[3] = {PyBUF_C_CONTIGUOUS,
                          PyBUF_C_CONTIGUOUS | PyBUF_WRITABLE | PyBUF_FORMAT,
                          PyBUF_C_CONTIGUOUS | PyBUF_WRITABLE};
    if (get_buffers(objs, views, flags, 3) < 0)
        return NULL;
    Py_buffer data = views[0], off = views[1], types = views[2];
    PyObject *result = NULL;
    const char *fmt = off.format ? off.format : "B";
    if (*fmt == '<' || *fmt == '=' || *fmt == '@')
        fmt++;
    int wide = off.itemsize == 8;
    if (!((off.itemsize == 4 && (*fmt == 'i' || *fmt == 'l')) ||
          (wide && (*fmt == 'l' || *fmt == 'q'))) || fmt[1] != '\0') {
        PyErr_SetString(PyExc_TypeError, "pairs: offsets must be an int32 or int64 buffer");
    } else if (data.itemsize != 1 || types.itemsize != 1) {
        PyErr_SetString(PyExc_TypeError, "pairs: data and types must be byte buffers");
    } else if (start < 0 || start > stop || stop > data.len - 2) {
        PyErr_SetString(PyExc_ValueError, "pairs: need 0 <= start <= stop <= len(data) - 2");
    } else if (!wide && stop > INT32_MAX) {
        PyErr_SetString(PyExc_ValueError, "pairs: offsets past 2**31 need an int64 buffer");
    } else {
        Py_ssize_t cap = off.len / off.itemsize, count = 0, reached;
        if (types.len < cap)
            cap = types.len;
        Py_BEGIN_ALLOW_THREADS
        reached = scan((const uint8_t *)data.buf, start, stop, off.buf, wide,
                       (uint8_t *)types.buf, cap, &count);
        Py_END_ALLOW_THREADS
        result = Py_BuildValue("nn", count, reached);
    }
    release_buffers(views, 3);
    return result;
}

/* Whether the ULog 'M' or 'Q' message from p to end (a byte, then an info: key length, key
 * "type name", value) is one pyulog reads without error, seen without decoding it: a text
 * (type "char[N]") or a 4-byte parameter value; 0: not known to be. As
 * mavsid.readers.ulog._checked, byte for byte. */
static int ulog_checked(const uint8_t *a, Py_ssize_t p, Py_ssize_t end)
{
    if (end - p < 5)
        return 0;
    Py_ssize_t key = p + 5, stop = key + a[p + 4];
    if (stop > end)
        return 0;
    if (stop - key >= 5 && memcmp(a + key, "char[", 5) == 0)
        return memchr(a + key + 5, ' ', (size_t)(stop - key - 5)) != NULL;
    if (end - stop != 4)
        return 0;
    return (stop - key >= 6 && memcmp(a + key, "float ", 6) == 0) ||
           (stop - key >= 8 && memcmp(a + key, "int32_t ", 8) == 0);
}

/* The ULog data walk: from a data message, the messages one after the other (each a uint16
 * size, a type byte, size bytes) as long as they are data messages ('D', size >= 2: their
 * positions, sizes and message ids written out), sync messages ('S') or 'M' / 'Q' messages
 * that carry nothing the reader keeps (ulog_checked; both stepped over), end inside the
 * buffer and no later than `until`. Every other message stops the walk there (the reader
 * reads it in Python, with pyulog's rules), as does an output without room.
 *
 * ulog_data(data, start, until, positions, sizes, ids) -> (count, reached)
 *   positions  a writable int64 buffer; sizes and ids writable uint16 buffers
 *   count      data messages written
 *   reached    where the walk stopped: the first message it did not take
 */
static PyObject *ulog_data(PyObject *self, PyObject *args)
{
    (void)self;
    PyObject *objs[4];
    Py_ssize_t start, until;
    if (!PyArg_ParseTuple(args, "OnnOOO:ulog_data", &objs[0], &start, &until, &objs[1],
                          &objs[2], &objs[3]))
        return NULL;
    Py_buffer views[4];
    const int out = PyBUF_C_CONTIGUOUS | PyBUF_WRITABLE;
    const int flags[4] = {PyBUF_C_CONTIGUOUS, out, out, out};
    if (get_buffers(objs, views, flags, 4) < 0)
        return NULL;
    Py_buffer data = views[0], pos = views[1], size = views[2], id = views[3];
    PyObject *result = NULL;
    if (data.itemsize != 1 || pos.itemsize != 8 || size.itemsize != 2 || id.itemsize != 2) {
        PyErr_SetString(PyExc_TypeError,
                        "ulog_data: bytes in; int64 positions, uint16 sizes and ids out");
    } else if (start < 0 || start > data.len) {
        PyErr_SetString(PyExc_ValueError, "ulog_data: start outside the data");
    } else {
        const uint8_t *a = (const uint8_t *)data.buf;
        int64_t *p_out = (int64_t *)pos.buf;
        uint16_t *s_out = (uint16_t *)size.buf, *i_out = (uint16_t *)id.buf;
        Py_ssize_t n = data.len, cap = pos.len / 8, p = start, c = 0;
        if (size.len / 2 < cap)
            cap = size.len / 2;
        if (id.len / 2 < cap)
            cap = id.len / 2;
        if (until > n)
            until = n;
        Py_BEGIN_ALLOW_THREADS
        while (p + 3 <= n) {
            Py_ssize_t length = (Py_ssize_t)(a[p] | (a[p + 1] << 8)), end = p + 3 + length;
            uint8_t kind = a[p + 2];
            if (end > until)
                break;
            if (kind == 'D') {
                if (length < 2 || c == cap)
                    break;
                p_out[c] = (int64_t)p;
                s_out[c] = (uint16_t)length;
                i_out[c] = (uint16_t)(a[p + 3] | (a[p + 4] << 8));
                c++;
            } else if (kind != 'S' &&
                       !((kind == 'M' || kind == 'Q') && ulog_checked(a, p, end))) {
                break;
            }
            p = end;
        }
        Py_END_ALLOW_THREADS
        result = Py_BuildValue("nn", c, p);
    }
    release_buffers(views, 4);
    return result;
}

/* The run of ULog 'M' / 'Q' messages from start that carry nothing the reader keeps
 * (ulog_checked), each ending by `until`: where it stops (start if none is). The
 * definitions section has runs of them (texts and defaults the reader only checks).
 *
 * ulog_infos(data, start, until) -> reached */
static PyObject *ulog_infos(PyObject *self, PyObject *args)
{
    (void)self;
    Py_buffer data;
    Py_ssize_t start, until;
    if (!PyArg_ParseTuple(args, "y*nn:ulog_infos", &data, &start, &until))
        return NULL;
    const uint8_t *a = (const uint8_t *)data.buf;
    Py_ssize_t n = data.len, p = start < 0 ? 0 : start;
    if (until > n)
        until = n;
    while (p + 3 <= n) {
        Py_ssize_t end = p + 3 + (Py_ssize_t)(a[p] | (a[p + 1] << 8));
        uint8_t kind = a[p + 2];
        if (end > until || !((kind == 'M' || kind == 'Q') && ulog_checked(a, p, end)))
            break;
        p = end;
    }
    PyBuffer_Release(&data);
    return PyLong_FromSsize_t(p);
}

/* A ULog format definition "name:type field;type[n] field;..." parsed as
 * mavsid.readers.ulog._parse_format does it, to the same objects: the text decoded as UTF-8
 * (invalid bytes dropped), its name (before the first ':'), its fields (between the first
 * and the second ':', split at ';', empty items skipped; each "type name ..." split at its
 * first space, the name the next word; an array "type[n]" with n read as int() reads it)
 * and its size in bytes when every field's type is in `sizes` (else -1).
 *
 * ulog_format(data, sizes) -> (name, ((type, count, name), ...), size)
 *   sizes  a dict: basic type name -> size in bytes
 * ValueError where _parse_format raises _Bad (no ':', an item without a space, a count that
 * is no number or is outside 0..65535). */
static Py_ssize_t find_char(int kind, const void *d, Py_ssize_t from, Py_ssize_t to,
                            Py_UCS4 c)
{
    for (Py_ssize_t i = from; i < to; i++)
        if (PyUnicode_READ(kind, d, i) == c)
            return i;
    return -1;
}

static PyObject *format_field(PyObject *text, int kind, const void *d, Py_ssize_t s,
                              Py_ssize_t e, PyObject *sizes, Py_ssize_t *size)
{
    Py_ssize_t sp = find_char(kind, d, s, e, ' ');
    if (sp < 0) {
        PyErr_SetString(PyExc_ValueError, "a format field without a space");
        return NULL;
    }
    Py_ssize_t name_end = find_char(kind, d, sp + 1, e, ' ');
    PyObject *fname = PyUnicode_Substring(text, sp + 1, name_end < 0 ? e : name_end);
    if (fname == NULL)
        return NULL;
    Py_ssize_t a = find_char(kind, d, s, sp, '['), count = 0;
    PyObject *type;
    if (a < 0) {
        type = PyUnicode_Substring(text, s, sp);
    } else {
        /* kind[a + 1 : kind.find("]")]: -1 (none) is up to the type's last character */
        Py_ssize_t rb = find_char(kind, d, s, sp, ']');
        Py_ssize_t lo = a + 1, hi = rb >= 0 ? rb : sp - 1;
        if (hi < lo)
            hi = lo;
        PyObject *digits = PyUnicode_Substring(text, lo, hi);
        PyObject *number = digits == NULL ? NULL : PyLong_FromUnicodeObject(digits, 10);
        Py_XDECREF(digits);
        if (number == NULL) {
            Py_DECREF(fname);
            return NULL;
        }
        int overflow = 0;
        long long value = PyLong_AsLongLongAndOverflow(number, &overflow);
        Py_DECREF(number);
        if (overflow || value < 0 || value > 0xFFFF) {
            Py_DECREF(fname);
            if (!PyErr_Occurred())
                PyErr_SetString(PyExc_ValueError, "an array count outside 0..65535");
            return NULL;
        }
        count = (Py_ssize_t)value;
        type = PyUnicode_Substring(text, s, a);
    }
    if (type == NULL) {
        Py_DECREF(fname);
        return NULL;
    }
    PyObject *width = PyDict_GetItemWithError(sizes, type);
    if (width == NULL && PyErr_Occurred()) {
        Py_DECREF(type);
        Py_DECREF(fname);
        return NULL;
    }
    if (width == NULL || *size < 0) {
        *size = -1;
    } else {
        Py_ssize_t w = PyLong_AsSsize_t(width);
        if (w == -1 && PyErr_Occurred()) {
            Py_DECREF(type);
            Py_DECREF(fname);
            return NULL;
        }
        *size += w * (count ? count : 1);
    }
    PyObject *field = Py_BuildValue("(NnN)", type, count, fname);
    return field;
}

static PyObject *ulog_format(PyObject *self, PyObject *args)
{
    (void)self;
    Py_buffer data;
    PyObject *sizes;
    if (!PyArg_ParseTuple(args, "y*O!:ulog_format", &data, &PyDict_Type, &sizes))
        return NULL;
    PyObject *text = PyUnicode_DecodeUTF8((const char *)data.buf, data.len, "ignore");
    PyBuffer_Release(&data);
    if (text == NULL)
        return NULL;
    PyObject *result = NULL, *name = NULL, *fields = NULL;
    int kind = PyUnicode_KIND(text);
    const void *d = PyUnicode_DATA(text);
    Py_ssize_t n = PyUnicode_GET_LENGTH(text), size = 0;
    Py_ssize_t c1 = find_char(kind, d, 0, n, ':');
    if (c1 < 0) {
        PyErr_SetString(PyExc_ValueError, "a format without ':'");
        goto done;
    }
    Py_ssize_t c2 = find_char(kind, d, c1 + 1, n, ':');
    if (c2 < 0)
        c2 = n;
    name = PyUnicode_Substring(text, 0, c1);
    fields = PyList_New(0);
    if (name == NULL || fields == NULL)
        goto done;
    for (Py_ssize_t s = c1 + 1; s <= c2;) {
        Py_ssize_t e = find_char(kind, d, s, c2, ';');
        if (e < 0)
            e = c2;
        if (e > s) {
            PyObject *field = format_field(text, kind, d, s, e, sizes, &size);
            if (field == NULL || PyList_Append(fields, field) < 0) {
                Py_XDECREF(field);
                goto done;
            }
            Py_DECREF(field);
        }
        s = e + 1;
    }
    PyObject *as_tuple = PyList_AsTuple(fields);
    if (as_tuple != NULL)
        result = Py_BuildValue("(ONn)", name, as_tuple, size);
done:
    Py_XDECREF(name);
    Py_XDECREF(fields);
    Py_DECREF(text);
    return result;
}

static PyMethodDef methods[] = {
    {"pairs", pairs, METH_VARARGS,
     "pairs(data, start, stop, offsets, types) -> (count, reached): the offsets of the "
     "0xA3 0x95 pairs at start..stop-1 of data and their type bytes, written to offsets "
     "and types; reached is stop, or where the outputs ran out of room."},
    {"ulog_data", ulog_data, METH_VARARGS,
     "ulog_data(data, start, until, positions, sizes, ids) -> (count, reached): the run of "
     "ULog data (and sync, and checked M/Q) messages from start, ending by until: the data "
     "messages' positions, sizes and ids written out; reached is the first message not "
     "taken."},
    {"ulog_infos", ulog_infos, METH_VARARGS,
     "ulog_infos(data, start, until) -> reached: the end of the run of ULog M / Q messages "
     "from start that carry nothing (as mavsid.readers.ulog._checked), ending by until."},
    {"ulog_format", ulog_format, METH_VARARGS,
     "ulog_format(data, sizes) -> (name, fields, size): a ULog format definition parsed as "
     "mavsid.readers.ulog._parse_format parses it (ValueError where it raises _Bad)."},
    {NULL, NULL, 0, NULL},
};

static struct PyModuleDef module = {
    PyModuleDef_HEAD_INIT, "_scan",
    "Readers' byte loops, compiled (mavsid.readers.dataflash._find_headers, "
    "mavsid.readers.ulog)", -1,
    methods, NULL, NULL, NULL, NULL,
};

PyMODINIT_FUNC PyInit__scan(void)
{
    PyObject *m = PyModule_Create(&module);
#ifdef MAVSID_SSE2
    const int vectorised = 1;
#else
    const int vectorised = 0; /* a byte loop: slower than numpy's vectorised compares */
#endif
    if (m != NULL && PyModule_AddIntConstant(m, "vectorised", vectorised) < 0) {
        Py_DECREF(m);
        return NULL;
    }
    return m;
}
