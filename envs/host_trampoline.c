/* The XLA:CPU FFI handler of envs/host_call.py: it hands each call's buffers to one Python function.
 *
 * XLA calls gsa_host_call(frame) for every custom call to its target (envs/xla_ffi.py registers it). The handler
 * answers XLA's metadata query (the FFI API version it was built against), skips the stages before execution,
 * and at execution calls the function set with gsa_set_dispatch with one int64 descriptor of the call:
 *
 *   [words, key, n_args, n_rets, then per buffer (arguments, then results): data, dtype, rank, dims[rank]]
 *
 * where key is the call's integer attribute "key" and dtype an XLA_FFI_DataType. The function returns NULL,
 * or a message that becomes the call's error (copied here). Built against jaxlib's xla/ffi/api/c_api.h.
 */
#include <stdint.h>
#include <string.h>

#include "xla/ffi/api/c_api.h"

#define MAX_WORDS 1024

typedef const char* (*gsa_dispatch_fn)(const int64_t* descriptor);

static gsa_dispatch_fn dispatch = NULL;

void gsa_set_dispatch(gsa_dispatch_fn fn) { dispatch = fn; }

static XLA_FFI_Error* fail(const XLA_FFI_CallFrame* frame, const char* message) {
  XLA_FFI_Error_Create_Args args;
  memset(&args, 0, sizeof(args));
  args.struct_size = XLA_FFI_Error_Create_Args_STRUCT_SIZE;
  args.message = message;
  args.errc = XLA_FFI_Error_Code_INTERNAL;
  return frame->api->XLA_FFI_Error_Create(&args);
}

static int find_key(const XLA_FFI_Attrs* attrs, int64_t* key) {
  for (int64_t i = 0; i < attrs->size; ++i) {
    const XLA_FFI_ByteSpan* name = attrs->names[i];
    if (attrs->types[i] == XLA_FFI_AttrType_SCALAR && name->len == 3 && memcmp(name->ptr, "key", 3) == 0) {
      const XLA_FFI_Scalar* scalar = (const XLA_FFI_Scalar*)attrs->attrs[i];
      if (scalar->dtype != XLA_FFI_DataType_S64) return 0;
      *key = *(const int64_t*)scalar->value;
      return 1;
    }
  }
  return 0;
}

/* Appends the buffers' data, dtype, rank and dims to out at *n; 0 where they would not fit. */
static int describe(void** buffers, int64_t count, int64_t* out, int64_t* n) {
  for (int64_t i = 0; i < count; ++i) {
    const XLA_FFI_Buffer* b = (const XLA_FFI_Buffer*)buffers[i];
    if (*n + 3 + b->rank > MAX_WORDS) return 0;
    out[(*n)++] = (int64_t)(intptr_t)b->data;
    out[(*n)++] = (int64_t)b->dtype;
    out[(*n)++] = b->rank;
    for (int64_t d = 0; d < b->rank; ++d) out[(*n)++] = b->dims[d];
  }
  return 1;
}

XLA_FFI_Error* gsa_host_call(XLA_FFI_CallFrame* frame) {
  if (frame->extension_start != NULL && frame->extension_start->type == XLA_FFI_Extension_Metadata) {
    XLA_FFI_Metadata* metadata = ((XLA_FFI_Metadata_Extension*)frame->extension_start)->metadata;
    metadata->api_version.major_version = XLA_FFI_API_MAJOR;
    metadata->api_version.minor_version = XLA_FFI_API_MINOR;
    metadata->traits = 0;
    return NULL;
  }
  if (frame->stage != XLA_FFI_ExecutionStage_EXECUTE) return NULL;
  int64_t descriptor[MAX_WORDS];
  int64_t n = 4;
  if (dispatch == NULL) return fail(frame, "gsa_host_call: no Python dispatch function set");
  if (!find_key(&frame->attrs, &descriptor[1])) return fail(frame, "gsa_host_call: no int64 attribute 'key'");
  descriptor[2] = frame->args.size;
  descriptor[3] = frame->rets.size;
  if (!describe(frame->args.args, frame->args.size, descriptor, &n) ||
      !describe(frame->rets.rets, frame->rets.size, descriptor, &n)) {
    return fail(frame, "gsa_host_call: too many buffers or dimensions");
  }
  descriptor[0] = n;
  const char* message = dispatch(descriptor);
  return message == NULL ? NULL : fail(frame, message);
}
