/* The loops of mavsid's readers that numpy does in several passes (or Python one step at a
 * time), compiled. Optional:
 * where the package is built without a C compiler the readers use their numpy code instead
 * (same results; tests compare the two).
 *
 * The DataFlash header scan: every 0xA3 0x95 byte pair of a buffer with the byte after it
 * (its message type), as mavsid.readers.dataflash_scan.find_headers_numpy finds them, in one
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

/* ------------------------------------------------------------------ the plain ULog read
 * ulog_plain(data, topics) -> None | (start_us, last_us, appended, truncated, params, rare,
 *                                     tables, times)
 *
 * A whole ULog read in one compiled pass, for the logs with nothing unusual in them (all
 * real flights seen so far): mavsid.readers.ulog's Python reader (pyulog's rules on damaged
 * files) is the reference and reads every other log. None is returned as soon as anything
 * is met that the Python reader would flag, resynchronise over or stop at: a bad header or
 * flag bits, a message cut inside the definitions, a format that does not parse plainly
 * (non-ASCII text, an odd array count), formats that contain themselves or nest too deeply, a
 * parameter of the definitions other than "float NAME" / "int32_t NAME" with a 4-byte
 * value, an implausible header (type 0, size 0 or > 10000), a sync magic inside a message of
 * an unknown type, a subscription that is repeated, unreadable or of a topic without room
 * for its timestamp, a data message without subscription or of another size than its
 * format's, a payload too short for its fixed fields, appended data at odd offsets. Where
 * it returns, the Python reader returns the same (tests compare the two on every log).
 *
 *   data      the file's bytes
 *   topics    a set of the topic names to decode, or None for all
 *   start_us  the header's timestamp; last_us pyulog's last timestamp (the largest
 *             `timestamp` of the decoded data messages, at least start_us)
 *   appended  the flag bits' appended-data bit; truncated the bytes of a last message cut
 *             by the end of the file
 *   params    the definitions' parameters: name -> float, in the file's order
 *   rare      (type, position, size, last_us so far) of the info (I), unchecked M and Q,
 *             logged (L, C), dropout (O) and parameter-change (P) messages, in order: the
 *             caller reads their payloads (few) with the Python reader's code
 *   tables    per subscription with data, sorted by topic and instance (pyulog's order,
 *             each section's subscriptions in reverse, where they tie): (topic, multi_id,
 *             layout, records, count); layout is (field names, type codes (bytes:
 *             _BASIC's order), offsets, record size, name -> index (empty: filled when
 *             first needed), the time fields it has of "timestamp" and "timestamp_sample"),
 *             shared by a topic's instances; records a bytearray of count records
 *   times     a bytearray of float64: each table's timestamp_sample (else timestamp) in
 *             seconds, NaN where it has neither, the tables one after the other */

#define UL_MAX_FIELDS 0xFFFF
#define UL_MAX_DEPTH 64
#define UL_MAX_UNKNOWN 10000
#define UL_MAX_LEAVES (1 << 20) /* fields of all the layouts of a read */

static const char *const ul_basic[12] = {"int8_t", "uint8_t", "int16_t", "uint16_t",
                                         "int32_t", "uint32_t", "int64_t", "uint64_t",
                                         "float", "double", "bool", "char"};
static const int ul_width[12] = {1, 1, 2, 2, 4, 4, 8, 8, 4, 8, 1, 1};

typedef struct {
    const uint8_t *s;
    Py_ssize_t n;
} UStr;

typedef struct {
    UStr type, name;
    int basic; /* code, or -1: a nested format */
    Py_ssize_t count;
} UField;

typedef struct {
    UStr name;
    UField *fields;
    Py_ssize_t nfields;
    int state; /* cycle search: 0 new, 1 on the path, 2 done */
    Py_ssize_t leaves; /* fields flattened (saturated); -1 not plain; -2 not counted yet */
} UFormat;

typedef struct {
    Py_ssize_t at, len, off; /* name in the arena; offset in the record */
    int code;
} ULeaf;

typedef struct {
    PyObject *py; /* (names, codes, offsets, size, index) */
    Py_ssize_t size, ts_off, time_off;
    int time_code; /* -1: no timestamp_sample nor timestamp */
} ULayout;

typedef struct {
    Py_ssize_t layout, count, first;
    PyObject *name;
    int multi_id, msg_id;
} USub;

typedef struct {
    const uint8_t *a;
    Py_ssize_t n;
    UFormat *fmts;
    Py_ssize_t nfmts, capfmts;
    Py_ssize_t *slots; /* hash of the formats' names: index + 1, 0 empty */
    Py_ssize_t nslots;
    ULayout *layouts;
    Py_ssize_t nlayouts, caplayouts;
    PyObject *layout_of; /* topic name -> layout index */
    USub *subs;
    Py_ssize_t nsubs, capsubs;
    int32_t lookup[1 << 16]; /* message id -> active subscription + 1, 0 none */
    uint8_t filtered[1 << 16]; /* message id subscribed for a topic not wanted */
    Py_ssize_t *active, nactive, capactive; /* the section's subscriptions, in order */
    Py_ssize_t *final, nfinal, capfinal;
    int64_t *msg_pos;
    int32_t *msg_sub;
    Py_ssize_t nmsg, capmsg, capsub_msgs;
    uint64_t last;
    Py_ssize_t truncated, skipped;
    int corrupt;
    uint8_t lost[1 << 13]; /* bits: message ids of data messages without subscription */
    PyObject *topics, *rare;
    /* the flattening's scratch: names in an arena, their codes and offsets */
    char *arena;
    Py_ssize_t alen, acap;
    ULeaf *leaf;
    Py_ssize_t nleaf, capleaf;
    char *prefix;
    Py_ssize_t plen, pcap;
    Py_ssize_t total_leaves;
} UPlain;

static int ul_grow(void **p, Py_ssize_t *cap, Py_ssize_t need, size_t item)
{
    if (need <= *cap)
        return 0;
    Py_ssize_t c = *cap ? *cap : 16;
    while (c < need)
        c *= 2;
    void *q = PyMem_Realloc(*p, (size_t)c * item);
    if (q == NULL) {
        PyErr_NoMemory();
        return -1;
    }
    *p = q;
    *cap = c;
    return 0;
}

static uint64_t ul_hash(const uint8_t *s, Py_ssize_t n)
{
    uint64_t h = 1469598103934665603ULL;
    for (Py_ssize_t i = 0; i < n; i++)
        h = (h ^ s[i]) * 1099511628211ULL;
    return h;
}

static Py_ssize_t ul_find(UPlain *u, const uint8_t *s, Py_ssize_t n)
{
    if (!u->nslots)
        return -1;
    for (uint64_t h = ul_hash(s, n) & (uint64_t)(u->nslots - 1);; h = (h + 1) & (uint64_t)(u->nslots - 1)) {
        Py_ssize_t k = u->slots[h];
        if (!k)
            return -1;
        UFormat *f = &u->fmts[k - 1];
        if (f->name.n == n && memcmp(f->name.s, s, (size_t)n) == 0)
            return k - 1;
    }
}

/* Put format k (the last added) in the hash, grown to twice the formats or more. */
static int ul_index(UPlain *u, Py_ssize_t k)
{
    if (2 * (u->nfmts + 1) > u->nslots) {
        Py_ssize_t want = 64;
        while (want < 2 * (u->nfmts + 1))
            want *= 2;
        Py_ssize_t *s = PyMem_Calloc((size_t)want, sizeof(Py_ssize_t));
        if (s == NULL) {
            PyErr_NoMemory();
            return -1;
        }
        PyMem_Free(u->slots);
        u->slots = s;
        u->nslots = want;
        k = 0; /* all of them again */
    }
    for (; k < u->nfmts; k++) {
        uint64_t mask = (uint64_t)(u->nslots - 1);
        uint64_t h = ul_hash(u->fmts[k].name.s, u->fmts[k].name.n) & mask;
        while (u->slots[h])
            h = (h + 1) & mask;
        u->slots[h] = k + 1;
    }
    return 0;
}

static int ul_basic_code(const uint8_t *s, Py_ssize_t n)
{
    static const int length[12] = {6, 7, 7, 8, 7, 8, 7, 8, 5, 6, 4, 4};
    for (int k = 0; k < 12; k++)
        if (length[k] == n && memcmp(ul_basic[k], s, (size_t)n) == 0)
            return k;
    return -1;
}

/* A format "name:type field;type[n] field;..." as _parse_format reads it, when plainly
 * (ASCII, counts of digits only): 1 added, 0 not plain, -1 an error set. */
static int ul_format(UPlain *u, const uint8_t *s, Py_ssize_t n)
{
    for (Py_ssize_t i = 0; i < n; i++)
        if (s[i] >= 0x80)
            return 0;
    const uint8_t *c1 = memchr(s, ':', (size_t)n);
    if (c1 == NULL)
        return 0;
    Py_ssize_t lo = c1 - s + 1, hi = n;
    const uint8_t *c2 = memchr(s + lo, ':', (size_t)(n - lo));
    if (c2 != NULL)
        hi = c2 - s;
    UField *fields = NULL;
    Py_ssize_t nf = 0, capf = 0;
    for (Py_ssize_t p = lo; p <= hi;) {
        const uint8_t *semi = memchr(s + p, ';', (size_t)(hi - p));
        Py_ssize_t e = semi ? semi - s : hi;
        if (e > p) {
            const uint8_t *sp = memchr(s + p, ' ', (size_t)(e - p));
            if (sp == NULL)
                goto not_plain;
            Py_ssize_t k_end = sp - s, nm = k_end + 1;
            const uint8_t *sp2 = memchr(s + nm, ' ', (size_t)(e - nm));
            Py_ssize_t nm_end = sp2 ? sp2 - s : e;
            UField f = {{s + p, k_end - p}, {s + nm, nm_end - nm}, -1, 0};
            const uint8_t *br = memchr(s + p, '[', (size_t)(k_end - p));
            if (br != NULL) {
                Py_ssize_t b = br - s;
                if (s[k_end - 1] != ']' || k_end - 1 <= b + 1 || k_end - 1 - (b + 1) > 5)
                    goto not_plain;
                Py_ssize_t count = 0;
                for (Py_ssize_t i = b + 1; i < k_end - 1; i++) {
                    if (s[i] < '0' || s[i] > '9')
                        goto not_plain;
                    count = count * 10 + (s[i] - '0');
                }
                if (count > 0xFFFF)
                    goto not_plain;
                f.count = count;
                f.type.n = b - p;
            }
            f.basic = ul_basic_code(f.type.s, f.type.n);
            if (ul_grow((void **)&fields, &capf, nf + 1, sizeof(UField)) < 0) {
                PyMem_Free(fields);
                return -1;
            }
            fields[nf++] = f;
        }
        p = e + 1;
    }
    Py_ssize_t k = ul_find(u, s, lo - 1);
    if (k >= 0) { /* a format defined again: the last definition holds */
        PyMem_Free(u->fmts[k].fields);
        u->fmts[k].fields = fields;
        u->fmts[k].nfields = nf;
        return 1;
    }
    if (ul_grow((void **)&u->fmts, &u->capfmts, u->nfmts + 1, sizeof(UFormat)) < 0) {
        PyMem_Free(fields);
        return -1;
    }
    UFormat *g = &u->fmts[u->nfmts++];
    g->name.s = s;
    g->name.n = lo - 1;
    g->fields = fields;
    g->nfields = nf;
    g->state = 0;
    g->leaves = -2;
    return ul_index(u, u->nfmts - 1) < 0 ? -1 : 1;
not_plain:
    PyMem_Free(fields);
    return 0;
}

/* Whether a format reaches itself through its nested types (undefined ones ignored). */
static int ul_cyclic(UPlain *u, Py_ssize_t k, int depth)
{
    UFormat *f = &u->fmts[k];
    if (f->state == 1 || depth > UL_MAX_DEPTH)
        return 1;
    if (f->state == 2)
        return 0;
    f->state = 1;
    for (Py_ssize_t i = 0; i < f->nfields; i++) {
        if (f->fields[i].basic >= 0)
            continue;
        Py_ssize_t j = ul_find(u, f->fields[i].type.s, f->fields[i].type.n);
        if (j >= 0 && ul_cyclic(u, j, depth + 1))
            return 1;
    }
    f->state = 2;
    return 0;
}

static int ul_push_prefix(UPlain *u, const uint8_t *s, Py_ssize_t n)
{
    if (ul_grow((void **)&u->prefix, &u->pcap, u->plen + n + 1, 1) < 0)
        return -1;
    memcpy(u->prefix + u->plen, s, (size_t)n);
    u->plen += n;
    return 0;
}

static int ul_leaf(UPlain *u, const uint8_t *s, Py_ssize_t n, const char *index, int code,
                   Py_ssize_t *off)
{
    Py_ssize_t il = index ? (Py_ssize_t)strlen(index) : 0, len = u->plen + n + il;
    if (u->nleaf >= UL_MAX_FIELDS)
        return 0;
    if (ul_grow((void **)&u->arena, &u->acap, u->alen + len, 1) < 0 ||
        ul_grow((void **)&u->leaf, &u->capleaf, u->nleaf + 1, sizeof(ULeaf)) < 0)
        return -1;
    if (len) {
        char *d = u->arena + u->alen;
        if (u->plen)
            memcpy(d, u->prefix, (size_t)u->plen);
        if (n)
            memcpy(d + u->plen, s, (size_t)n);
        if (il)
            memcpy(d + u->plen + n, index, (size_t)il);
    }
    ULeaf *l = &u->leaf[u->nleaf++];
    l->at = u->alen;
    l->len = len;
    l->off = *off;
    l->code = code;
    u->alen += len;
    *off += ul_width[code];
    return 1;
}

/* The fields format k flattens to (more than UL_MAX_FIELDS: UL_MAX_FIELDS + 1); -1 where
 * it nests an undefined type or nests too deeply (the formats are free of cycles). */
static Py_ssize_t ul_leaves(UPlain *u, Py_ssize_t k, int depth)
{
    UFormat *f = &u->fmts[k];
    if (f->leaves != -2)
        return f->leaves;
    if (depth > UL_MAX_DEPTH)
        return -1;
    Py_ssize_t total = 0;
    for (Py_ssize_t i = 0; i < f->nfields && total >= 0; i++) {
        UField *x = &f->fields[i];
        Py_ssize_t reps = x->count ? x->count : 1, each = 1;
        if (x->basic < 0) {
            Py_ssize_t inner = ul_find(u, x->type.s, x->type.n);
            each = inner < 0 ? -1 : ul_leaves(u, inner, depth + 1);
        }
        if (each < 0)
            total = -1;
        else if (each && reps > (UL_MAX_FIELDS + 1) / each) /* (no product overflows) */
            total = UL_MAX_FIELDS + 1;
        else if ((total += reps * each) > UL_MAX_FIELDS)
            total = UL_MAX_FIELDS + 1;
    }
    return f->leaves = total;
}

/* "[r]" (r < 65536) into out. */
static void ul_index_text(char *out, Py_ssize_t r)
{
    char digits[8];
    int k = 0;
    do {
        digits[k++] = (char)('0' + r % 10);
        r /= 10;
    } while (r);
    *out++ = '[';
    while (k)
        *out++ = digits[--k];
    *out++ = ']';
    *out = '\0';
}

/* The leaves of format k under the current prefix (_new_layout's flatten): 1 done, 0 not
 * plain (an undefined type, too many fields or too deep), -1 an error set. */
static int ul_flatten(UPlain *u, Py_ssize_t k, int depth, Py_ssize_t *off)
{
    if (depth > UL_MAX_DEPTH)
        return 0;
    UFormat *f = &u->fmts[k];
    for (Py_ssize_t i = 0; i < f->nfields; i++) {
        UField *x = &f->fields[i];
        Py_ssize_t reps = x->count ? x->count : 1, inner = -1;
        if (x->basic < 0) {
            inner = ul_find(u, x->type.s, x->type.n);
            Py_ssize_t each = inner < 0 ? -1 : ul_leaves(u, inner, depth + 1);
            if (each < 0)
                return 0;
            if (each == 0)
                continue; /* (adds no field, however often repeated) */
        }
        for (Py_ssize_t r = 0; r < reps; r++) {
            char index[16];
            if (x->count)
                ul_index_text(index, r);
            int got;
            if (x->basic >= 0) {
                got = ul_leaf(u, x->name.s, x->name.n, x->count ? index : NULL, x->basic, off);
            } else {
                Py_ssize_t keep = u->plen;
                if (ul_push_prefix(u, x->name.s, x->name.n) < 0 ||
                    (x->count && ul_push_prefix(u, (const uint8_t *)index,
                                                (Py_ssize_t)strlen(index)) < 0) ||
                    ul_push_prefix(u, (const uint8_t *)".", 1) < 0)
                    return -1;
                got = ul_flatten(u, inner, depth + 1, off);
                u->plen = keep;
            }
            if (got <= 0)
                return got;
        }
    }
    return 1;
}

/* Whether two of the first m leaves have the same name: 1, 0, -1 an error set. */
static int ul_repeated(UPlain *u, Py_ssize_t m)
{
    Py_ssize_t size = 16;
    while (size < 2 * m)
        size *= 2;
    Py_ssize_t *slot = PyMem_Calloc((size_t)size, sizeof(Py_ssize_t));
    if (slot == NULL) {
        PyErr_NoMemory();
        return -1;
    }
    int found = 0;
    for (Py_ssize_t i = 0; i < m && !found; i++) {
        const uint8_t *s = (const uint8_t *)u->arena + u->leaf[i].at;
        Py_ssize_t n = u->leaf[i].len;
        uint64_t h = ul_hash(s, n) & (uint64_t)(size - 1);
        for (; slot[h]; h = (h + 1) & (uint64_t)(size - 1)) {
            const ULeaf *o = &u->leaf[slot[h] - 1];
            if (o->len == n && memcmp(u->arena + o->at, s, (size_t)n) == 0) {
                found = 1;
                break;
            }
        }
        slot[h] = i + 1;
    }
    PyMem_Free(slot);
    return found;
}

/* The layout of topic `name` (its format's fields flattened, trailing padding dropped,
 * empty names f<i>): its index, -1 not plain (no format, repeated names...), -2 an error.
 * Its name -> index dict is left empty, for the reader to fill when first needed. */
static Py_ssize_t ul_layout(UPlain *u, PyObject *name, const uint8_t *s, Py_ssize_t n)
{
    PyObject *got = PyDict_GetItemWithError(u->layout_of, name);
    if (got != NULL)
        return PyLong_AsSsize_t(got);
    if (PyErr_Occurred())
        return -2;
    Py_ssize_t k = ul_find(u, s, n);
    if (k < 0)
        return -1;
    Py_ssize_t leaves = ul_leaves(u, k, 0);
    if (leaves < 0 || leaves > UL_MAX_FIELDS || u->total_leaves + leaves > UL_MAX_LEAVES)
        return -1; /* (the Python reader keeps layouts within a budget) */
    u->total_leaves += leaves;
    u->alen = u->nleaf = u->plen = 0;
    Py_ssize_t off = 0;
    int ok = ul_flatten(u, k, 0, &off);
    if (ok <= 0)
        return ok < 0 ? -2 : -1;
    Py_ssize_t m = u->nleaf;
    while (m && u->leaf[m - 1].len >= 8 &&
           memcmp(u->arena + u->leaf[m - 1].at, "_padding", 8) == 0)
        m--;
    for (Py_ssize_t i = 0; i < m; i++) { /* an empty name is f<i>, as pyulog's dtype has it */
        if (u->leaf[i].len)
            continue;
        char text[24];
        int tl = snprintf(text, sizeof text, "f%zd", i);
        if (ul_grow((void **)&u->arena, &u->acap, u->alen + tl, 1) < 0)
            return -2;
        memcpy(u->arena + u->alen, text, (size_t)tl);
        u->leaf[i].at = u->alen;
        u->leaf[i].len = tl;
        u->alen += tl;
    }
    int repeated = ul_repeated(u, m);
    if (repeated)
        return repeated < 0 ? -2 : -1; /* repeated names: numpy refuses them */
    PyObject *names = PyTuple_New(m), *offsets = PyTuple_New(m), *index = PyDict_New();
    PyObject *codes = PyBytes_FromStringAndSize(NULL, m), *stamps = NULL;
    ULayout lay = {NULL, 0, -1, 0, -1};
    Py_ssize_t ts_sample = -1, ts = -1;
    if (names == NULL || offsets == NULL || index == NULL || codes == NULL)
        goto fail;
    for (Py_ssize_t i = 0; i < m; i++) {
        const ULeaf *l = &u->leaf[i];
        const char *t = u->arena + l->at;
        Py_ssize_t tl = l->len;
        PyBytes_AS_STRING(codes)[i] = (char)l->code;
        PyObject *nm = PyUnicode_DecodeASCII(t, tl, NULL), *o = PyLong_FromSsize_t(l->off);
        if (nm == NULL || o == NULL) {
            Py_XDECREF(nm);
            Py_XDECREF(o);
            goto fail;
        }
        PyTuple_SET_ITEM(names, i, nm);
        PyTuple_SET_ITEM(offsets, i, o);
        if (tl == 9 && memcmp(t, "timestamp", 9) == 0)
            ts = i;
        if (tl == 16 && memcmp(t, "timestamp_sample", 16) == 0)
            ts_sample = i;
    }
    stamps = ts >= 0 && ts_sample >= 0 ? Py_BuildValue("(ss)", "timestamp", "timestamp_sample")
             : ts >= 0 ? Py_BuildValue("(s)", "timestamp")
             : ts_sample >= 0 ? Py_BuildValue("(s)", "timestamp_sample") : PyTuple_New(0);
    if (stamps == NULL)
        goto fail;
    lay.size = m ? u->leaf[m - 1].off + ul_width[u->leaf[m - 1].code] : 0;
    lay.ts_off = ts >= 0 ? u->leaf[ts].off : lay.size;
    Py_ssize_t t = ts_sample >= 0 ? ts_sample : ts;
    if (t >= 0) {
        lay.time_off = u->leaf[t].off;
        lay.time_code = u->leaf[t].code;
    }
    lay.py = Py_BuildValue("(NNNnNN)", names, codes, offsets, lay.size, index, stamps);
    if (lay.py == NULL)
        return -2;
    if (ul_grow((void **)&u->layouts, &u->caplayouts, u->nlayouts + 1, sizeof(ULayout)) < 0) {
        Py_DECREF(lay.py);
        return -2;
    }
    u->layouts[u->nlayouts] = lay;
    PyObject *idx = PyLong_FromSsize_t(u->nlayouts);
    if (idx == NULL || PyDict_SetItem(u->layout_of, name, idx) < 0) {
        Py_XDECREF(idx);
        Py_DECREF(lay.py);
        return -2;
    }
    Py_DECREF(idx);
    return u->nlayouts++;
fail:
    Py_XDECREF(names);
    Py_XDECREF(offsets);
    Py_XDECREF(index);
    Py_XDECREF(codes);
    Py_XDECREF(stamps);
    return -2;
}

static uint64_t ul_u64(const uint8_t *p)
{
    uint64_t v;
    memcpy(&v, p, 8);
    return v; /* (little-endian hosts: x86, ARM) */
}

static int ul_rare(UPlain *u, int kind, Py_ssize_t pos, Py_ssize_t size)
{
    PyObject *t = Py_BuildValue("(innK)", kind, pos, size, (unsigned long long)u->last);
    if (t == NULL || PyList_Append(u->rare, t) < 0) {
        Py_XDECREF(t);
        return -1;
    }
    Py_DECREF(t);
    return 0;
}

/* A subscription: 1 taken, 0 not plain, -1 an error set. */
static int ul_subscribe(UPlain *u, Py_ssize_t pos, Py_ssize_t size)
{
    const uint8_t *d = u->a + pos + 3;
    if (size < 3)
        return 0;
    for (Py_ssize_t i = 3; i < size; i++)
        if (d[i] >= 0x80)
            return 0;
    int multi_id = d[0], msg_id = d[1] | d[2] << 8;
    if (u->lookup[msg_id]) /* subscribed again within a section */
        return 0;
    PyObject *name = PyUnicode_DecodeASCII((const char *)d + 3, size - 3, NULL);
    if (name == NULL)
        return -1;
    Py_ssize_t k = ul_layout(u, name, d + 3, size - 3);
    if (k < 0) {
        Py_DECREF(name);
        return k == -1 ? 0 : -1;
    }
    int wanted = 1;
    if (u->topics != Py_None && (wanted = PySet_Contains(u->topics, name)) < 0) {
        Py_DECREF(name);
        return -1;
    }
    if (!wanted) {
        u->filtered[msg_id] = 1;
        Py_DECREF(name);
        return 1;
    }
    if (u->layouts[k].ts_off + 8 > u->layouts[k].size) { /* no room for the timestamp */
        Py_DECREF(name);
        return 0;
    }
    if (ul_grow((void **)&u->subs, &u->capsubs, u->nsubs + 1, sizeof(USub)) < 0 ||
        ul_grow((void **)&u->active, &u->capactive, u->nactive + 1, sizeof(Py_ssize_t)) < 0) {
        Py_DECREF(name);
        return -1;
    }
    USub *s = &u->subs[u->nsubs];
    s->layout = k;
    s->count = 0;
    s->name = name;
    s->multi_id = multi_id;
    s->msg_id = msg_id;
    u->lookup[msg_id] = (int32_t)u->nsubs + 1;
    u->active[u->nactive++] = u->nsubs++;
    return 1;
}

static int ul_end_section(UPlain *u)
{
    if (ul_grow((void **)&u->final, &u->capfinal, u->nfinal + u->nactive, sizeof(Py_ssize_t)) < 0)
        return -1;
    for (Py_ssize_t i = u->nactive; i-- > 0;) {
        u->final[u->nfinal++] = u->active[i];
        u->lookup[u->subs[u->active[i]].msg_id] = 0;
    }
    u->nactive = 0;
    return 0;
}

static const uint8_t ul_sync[8] = {0x2f, 0x73, 0x13, 0x20, 0x25, 0x0c, 0xbb, 0x12};

/* The first sync magic at from..to - 8, -1 if none. */
static Py_ssize_t ul_find_sync(const uint8_t *a, Py_ssize_t from, Py_ssize_t to)
{
    for (Py_ssize_t i = from; i + 8 <= to; i++) {
        const uint8_t *q = memchr(a + i, ul_sync[0], (size_t)(to - 8 + 1 - i));
        if (q == NULL)
            return -1;
        i = q - a;
        if (memcmp(q, ul_sync, 8) == 0)
            return i;
    }
    return -1;
}

/* The data section from pos up to until (a message passing it ends the section), as the
 * Python reader's _Reader.data walks it: 1 done, 0 not plain, -1 an error set. */
static int ul_section(UPlain *u, Py_ssize_t pos, Py_ssize_t until, int final)
{
    const uint8_t *a = u->a;
    Py_ssize_t n = u->n;
    for (;;) {
        if (pos + 3 > n) {
            if (final && pos < n)
                u->truncated = n - pos;
            return 1;
        }
        Py_ssize_t size = a[pos] | a[pos + 1] << 8, end = pos + 3 + size;
        int kind = a[pos + 2];
        if (kind == 'D' && size >= 2 && end <= n && end <= until) {
            int msg_id = a[pos + 3] | a[pos + 4] << 8;
            int32_t k = u->lookup[msg_id] - 1;
            if (k < 0 && !u->filtered[msg_id]) { /* no subscription: skipped */
                u->lost[msg_id >> 3] |= (uint8_t)(1 << (msg_id & 7));
                u->skipped += size + 3;
                u->corrupt = 1;
            } else if (k >= 0 && size - 2 != u->layouts[u->subs[k].layout].size) {
                u->skipped += size + 3; /* another size than its format's: skipped */
                u->corrupt = 1;
            } else if (k >= 0) {
                USub *s = &u->subs[k];
                const ULayout *l = &u->layouts[s->layout];
                if (ul_grow((void **)&u->msg_pos, &u->capmsg, u->nmsg + 1, sizeof(int64_t)) < 0)
                    return -1;
                if (u->capmsg > u->capsub_msgs) {
                    void *q = PyMem_Realloc(u->msg_sub, (size_t)u->capmsg * sizeof(int32_t));
                    if (q == NULL)
                        return PyErr_NoMemory(), -1;
                    u->msg_sub = q;
                    u->capsub_msgs = u->capmsg;
                }
                u->msg_pos[u->nmsg] = pos;
                u->msg_sub[u->nmsg++] = k;
                s->count++;
                uint64_t t = ul_u64(a + pos + 5 + l->ts_off);
                if (t > u->last)
                    u->last = t;
            }
            pos = end;
            continue;
        }
        if (end > n) {
            if (final)
                u->truncated = n - pos;
            return 1;
        }
        if (end > until)
            return 1;
        if (kind == 'S' || ((kind == 'M' || kind == 'Q') && ulog_checked(a, pos, end))) {
            pos = end;
            continue;
        }
        switch (kind) {
        case 'A': {
            int got = ul_subscribe(u, pos, size);
            if (got <= 0)
                return got;
            break;
        }
        case 'L':
        case 'C':
        case 'O':
        case 'I':
        case 'M':
        case 'P':
        case 'Q':
            if ((kind == 'L' && size < 9) || (kind == 'C' && size < 11) ||
                (kind == 'O' && size != 2))
                return 0; /* too short: the Python reader ends the section there */
            if (ul_rare(u, kind, pos, size) < 0)
                return -1;
            break;
        case 'D': /* under 2 bytes */
            return 0;
        default:
            if (kind == 0 || size == 0 || size > UL_MAX_UNKNOWN) {
                /* an implausible header: on after the next sync magic (none: not plain) */
                Py_ssize_t k = ul_find_sync(a, pos + 1, n);
                if (k < 0)
                    return 0;
                u->corrupt = 1;
                u->skipped += k + 8 - pos;
                pos = k + 8;
                continue;
            }
            if (size >= 8) { /* a sync magic inside a message of an unknown type: on after it */
                Py_ssize_t k = ul_find_sync(a, pos + 3, end);
                if (k >= 0) {
                    u->corrupt = 1;
                    u->skipped += k + 8 - (pos + 3);
                    end = k + 8;
                }
            }
        }
        pos = end;
    }
}

/* The definitions from byte 16: the data section's start, 0 not plain, -1 an error set. */
static Py_ssize_t ul_definitions(UPlain *u, PyObject *params, int *appended,
                                 uint64_t offsets[3], int *noffsets)
{
    const uint8_t *a = u->a;
    Py_ssize_t n = u->n, pos = 16;
    int plain;
    while (pos < n) {
        if (n - pos < 3)
            return 0;
        Py_ssize_t size = a[pos] | a[pos + 1] << 8, end = pos + 3 + size;
        int kind = a[pos + 2];
        if (kind == 'A' || kind == 'L' || kind == 'C')
            return pos;
        if (end > n)
            return 0;
        const uint8_t *d = a + pos + 3;
        switch (kind) {
        case 'P': {
            if (size < 1)
                return 0;
            Py_ssize_t klen = d[0];
            int is_float = klen >= 6 && memcmp(d + 1, "float ", 6) == 0;
            int is_int = klen >= 8 && memcmp(d + 1, "int32_t ", 8) == 0;
            if (size != klen + 5 || !(is_float || is_int))
                return 0;
            Py_ssize_t skip = is_float ? 6 : 8;
            const uint8_t *nm = d + 1 + skip, *v = d + 1 + klen;
            Py_ssize_t nl = klen - skip;
            if (memchr(nm, ' ', (size_t)nl) || memchr(nm, '\n', (size_t)nl))
                return 0;
            double value;
            if (is_float) {
                float f;
                memcpy(&f, v, 4);
                value = (double)f;
            } else {
                int32_t i;
                memcpy(&i, v, 4);
                value = (double)i;
            }
            PyObject *key = PyUnicode_DecodeUTF8((const char *)nm, nl, "ignore");
            PyObject *val = key == NULL ? NULL : PyFloat_FromDouble(value);
            int bad = val == NULL || PyDict_SetItem(params, key, val) < 0;
            Py_XDECREF(key);
            Py_XDECREF(val);
            if (bad)
                return -1;
            break;
        }
        case 'F': /* (0: not plain, -1: an error) */
            if ((plain = ul_format(u, d, size)) <= 0)
                return plain;
            break;
        case 'I':
        case 'M':
        case 'Q':
            if ((kind == 'M' || kind == 'Q') && ulog_checked(a, pos, end))
                break;
            if (ul_rare(u, kind, pos, size) < 0)
                return -1;
            break;
        case 'B': {
            if (pos != 16 || size != 40)
                return 0;
            if (d[8] & ~1)
                return 0;
            for (int i = 9; i < 16; i++)
                if (d[i])
                    return 0;
            *appended = d[8] & 1;
            *noffsets = 0;
            for (int i = 0; i < 3; i++) {
                offsets[i] = ul_u64(d + 16 + 8 * i);
                if (offsets[i])
                    *noffsets = i + 1;
            }
            break;
        }
        default: /* another type: stepped over, as the Python reader does, if plausible */
            if (kind == 0 || size == 0 || size > UL_MAX_UNKNOWN)
                return 0;
            break;
        }
        pos = end;
    }
    return n;
}

static void ul_free(UPlain *u)
{
    for (Py_ssize_t k = 0; k < u->nfmts; k++)
        PyMem_Free(u->fmts[k].fields);
    PyMem_Free(u->fmts);
    PyMem_Free(u->slots);
    for (Py_ssize_t k = 0; k < u->nlayouts; k++)
        Py_XDECREF(u->layouts[k].py);
    PyMem_Free(u->layouts);
    Py_XDECREF(u->layout_of);
    for (Py_ssize_t k = 0; k < u->nsubs; k++)
        Py_XDECREF(u->subs[k].name);
    PyMem_Free(u->subs);
    PyMem_Free(u->active);
    PyMem_Free(u->final);
    PyMem_Free(u->msg_pos);
    PyMem_Free(u->msg_sub);
    PyMem_Free(u->arena);
    PyMem_Free(u->leaf);
    PyMem_Free(u->prefix);
    Py_XDECREF(u->rare);
    PyMem_Free(u);
}

static double ul_value(const uint8_t *p, int code)
{
    switch (code) {
    case 0: case 10: case 11: return (double)(int8_t)p[0];
    case 1: return (double)p[0];
    case 2: { int16_t v; memcpy(&v, p, 2); return (double)v; }
    case 3: { uint16_t v; memcpy(&v, p, 2); return (double)v; }
    case 4: { int32_t v; memcpy(&v, p, 4); return (double)v; }
    case 5: { uint32_t v; memcpy(&v, p, 4); return (double)v; }
    case 6: { int64_t v; memcpy(&v, p, 8); return (double)v; }
    case 7: { uint64_t v; memcpy(&v, p, 8); return (double)v; }
    case 8: { float v; memcpy(&v, p, 4); return (double)v; }
    default: { double v; memcpy(&v, p, 8); return v; }
    }
}

/* Tables in the order of their topic names (ASCII: byte order), instance numbers and
 * then pyulog's order (as the reader's stable sort puts them). */
typedef struct {
    const char *name;
    Py_ssize_t len, order;
    int multi_id;
} UOrder;

static int ul_order(const void *x, const void *y)
{
    const UOrder *a = x, *b = y;
    int c = memcmp(a->name, b->name, (size_t)(a->len < b->len ? a->len : b->len));
    if (c)
        return c;
    if (a->len != b->len)
        return a->len < b->len ? -1 : 1;
    if (a->multi_id != b->multi_id)
        return a->multi_id < b->multi_id ? -1 : 1;
    return a->order < b->order ? -1 : a->order > b->order;
}

/* Each subscription's records gathered (and its times), sorted as ul_order sorts. */
static PyObject *ul_tables(UPlain *u, PyObject **times_out)
{
    PyObject *times = NULL, *out = PyList_New(0);
    PyObject **records = PyMem_Calloc((size_t)(u->nsubs ? u->nsubs : 1), sizeof(PyObject *));
    char **dest = PyMem_Calloc((size_t)(u->nsubs ? u->nsubs : 1), sizeof(char *));
    UOrder *order = PyMem_Malloc((size_t)(u->nfinal ? u->nfinal : 1) * sizeof(UOrder));
    Py_ssize_t m = 0, total = 0;
    if (out == NULL || records == NULL || dest == NULL || order == NULL) {
        if (out != NULL)
            PyErr_NoMemory();
        goto fail;
    }
    /* the tables (subscriptions with records) in order; each's times at its place in it */
    for (Py_ssize_t f = 0; f < u->nfinal; f++) {
        USub *s = &u->subs[u->final[f]];
        if (!s->count || !u->layouts[s->layout].size)
            continue;
        order[m].name = PyUnicode_AsUTF8AndSize(s->name, &order[m].len);
        if (order[m].name == NULL)
            goto fail;
        order[m].order = f;
        order[m++].multi_id = s->multi_id;
    }
    qsort(order, (size_t)m, sizeof(UOrder), ul_order);
    for (Py_ssize_t i = 0; i < m; i++) {
        Py_ssize_t k = u->final[order[i].order];
        USub *s = &u->subs[k];
        s->first = total;
        total += s->count;
        records[k] = PyByteArray_FromStringAndSize(NULL, s->count * u->layouts[s->layout].size);
        if (records[k] == NULL)
            goto fail;
    }
    times = PyByteArray_FromStringAndSize(NULL, total * (Py_ssize_t)sizeof(double));
    if (times == NULL)
        goto fail;
    const uint8_t *a = u->a;
    double *t = (double *)PyByteArray_AS_STRING(times);
    for (Py_ssize_t k = 0; k < u->nsubs; k++) /* each table's next record */
        dest[k] = records[k] == NULL ? NULL : PyByteArray_AS_STRING(records[k]);
    Py_BEGIN_ALLOW_THREADS /* (plain copies: other threads' reads go on meanwhile) */
    for (Py_ssize_t i = 0; i < u->nmsg; i++) {
        Py_ssize_t k = u->msg_sub[i];
        USub *s = &u->subs[k];
        const ULayout *l = &u->layouts[s->layout];
        if (dest[k] == NULL)
            continue;
        const uint8_t *rec = a + u->msg_pos[i] + 5;
        memcpy(dest[k], rec, (size_t)l->size);
        dest[k] += l->size;
        t[s->first++] = l->time_code < 0 ? Py_NAN /* (first: the next time's place) */
                        : ul_value(rec + l->time_off, l->time_code) / 1e6;
    }
    Py_END_ALLOW_THREADS
    for (Py_ssize_t i = 0; i < m; i++) {
        Py_ssize_t k = u->final[order[i].order];
        USub *s = &u->subs[k];
        PyObject *row = Py_BuildValue("(OiOOn)", s->name, s->multi_id,
                                      u->layouts[s->layout].py, records[k], s->count);
        if (row == NULL || PyList_Append(out, row) < 0) {
            Py_XDECREF(row);
            goto fail;
        }
        Py_DECREF(row);
    }
    for (Py_ssize_t k = 0; k < u->nsubs; k++)
        Py_XDECREF(records[k]);
    PyMem_Free(records);
    PyMem_Free(dest);
    PyMem_Free(order);
    *times_out = times;
    return out;
fail:
    if (records != NULL)
        for (Py_ssize_t k = 0; k < u->nsubs; k++)
            Py_XDECREF(records[k]);
    PyMem_Free(records);
    PyMem_Free(dest);
    PyMem_Free(order);
    Py_XDECREF(times);
    Py_XDECREF(out);
    return NULL;
}

static PyObject *ulog_plain(PyObject *self, PyObject *args)
{
    (void)self;
    Py_buffer data;
    PyObject *topics;
    if (!PyArg_ParseTuple(args, "y*O:ulog_plain", &data, &topics))
        return NULL;
    if (topics != Py_None && !PyAnySet_Check(topics)) {
        PyBuffer_Release(&data);
        PyErr_SetString(PyExc_TypeError, "ulog_plain: topics must be a set or None");
        return NULL;
    }
    PyObject *result = NULL, *params = NULL, *tables = NULL, *times = NULL, *lost = NULL;
    UPlain *u = PyMem_Calloc(1, sizeof(UPlain));
    if (u == NULL) {
        PyBuffer_Release(&data);
        return PyErr_NoMemory();
    }
    u->a = (const uint8_t *)data.buf;
    u->n = data.len;
    u->topics = topics;
    u->layout_of = PyDict_New();
    u->rare = PyList_New(0);
    params = PyDict_New();
    if (u->layout_of == NULL || u->rare == NULL || params == NULL)
        goto done;
    const uint8_t magic[7] = {'U', 'L', 'o', 'g', 0x01, 0x12, 0x35};
    if (u->n < 16 || memcmp(u->a, magic, 7) != 0 || u->a[7] > 1)
        goto plain_no;
    uint64_t start_us = ul_u64(u->a + 8), offsets[3] = {0, 0, 0};
    u->last = start_us;
    int appended = 0, noffsets = 0;
    Py_ssize_t pos = ul_definitions(u, params, &appended, offsets, &noffsets);
    if (pos < 0)
        goto done;
    if (pos == 0)
        goto plain_no;
    for (Py_ssize_t k = 0; k < u->nfmts; k++)
        if (ul_cyclic(u, k, 0))
            goto plain_no;
    /* the sections: up to each appended-data offset (increasing, inside the file only),
     * then to the end */
    int sections = appended ? noffsets : 0;
    for (int i = 0; i <= sections; i++) {
        Py_ssize_t until = PY_SSIZE_T_MAX;
        if (i < sections) {
            if (offsets[i] < (uint64_t)pos || offsets[i] > (uint64_t)u->n)
                goto plain_no;
            until = (Py_ssize_t)offsets[i];
        }
        int got = ul_section(u, pos, until, i == sections);
        if (got < 0 || (got > 0 && ul_end_section(u) < 0))
            goto done;
        if (got == 0)
            goto plain_no;
        pos = until;
    }
    tables = ul_tables(u, &times);
    if (tables == NULL)
        goto done;
    lost = PyList_New(0);
    if (lost == NULL)
        goto done;
    for (int m = 0; u->corrupt && m < (1 << 16); m++) {
        if (!u->lost[m >> 3]) {
            m |= 7; /* (the byte's other ids: none) */
            continue;
        }
        if (!(u->lost[m >> 3] >> (m & 7) & 1))
            continue;
        PyObject *id = PyLong_FromLong(m);
        if (id == NULL || PyList_Append(lost, id) < 0) {
            Py_XDECREF(id);
            goto done;
        }
        Py_DECREF(id);
    }
    result = Py_BuildValue("(KKinOOOOniO)", (unsigned long long)start_us,
                           (unsigned long long)u->last, appended, u->truncated, params,
                           u->rare, tables, times, u->skipped, u->corrupt, lost);
    goto done;
plain_no:
    result = Py_NewRef(Py_None);
done:
    Py_XDECREF(params);
    Py_XDECREF(tables);
    Py_XDECREF(times);
    Py_XDECREF(lost);
    ul_free(u);
    PyBuffer_Release(&data);
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
    {"ulog_plain", ulog_plain, METH_VARARGS,
     "ulog_plain(data, topics) -> None | (start_us, last_us, appended, truncated, params, "
     "rare, tables, times): a ULog with nothing unusual read in one pass (None: read it "
     "with the Python reader); see the comment above it in _scan.c."},
    {"ulog_format", ulog_format, METH_VARARGS,
     "ulog_format(data, sizes) -> (name, fields, size): a ULog format definition parsed as "
     "mavsid.readers.ulog._parse_format parses it (ValueError where it raises _Bad)."},
    {NULL, NULL, 0, NULL},
};

static struct PyModuleDef module = {
    PyModuleDef_HEAD_INIT, "_scan",
    "Readers' byte loops, compiled (mavsid.readers.dataflash_scan.find_headers, "
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
