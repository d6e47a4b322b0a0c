// Material Structures: exact per-texel table lookups from float (Non-Color) EXRs.
//
// Cycles 5.2 filters texture() lookups even when "closest" is asked for, so coordinates are snapped
// to the texel centre first: any filter then returns the stored value exactly. The table size is
// passed in by the add-on (gettextureinfo(..., "resolution", ...) crashes Cycles 5.2 on the CPU).
// flip_t comes from the add-on too: 0 on Blender 5.x, 1 on 4.5, so that row 0 is the bottom row.

// Value of texel (column i, row j) of a width x height table, row 0 = bottom row of the image.
color ms_texel_fetch(string file, int i, int j, int width, int height, int flip_t)
{
    float s = (float(i) + 0.5) / float(width);
    float t = (float(j) + 0.5) / float(height);
    if (flip_t)
        t = 1.0 - t;
    return (color) texture(file, s, t, "interp", "closest", "wrap", "clamp");
}

// Value of the texel under the UV coordinate (u, v) in [0, 1)^2.
color ms_texel_at_uv(string file, float u, float v, int width, int height, int flip_t)
{
    int i = clamp(int(floor(u * width)), 0, width - 1);
    int j = clamp(int(floor(v * height)), 0, height - 1);
    return ms_texel_fetch(file, i, j, width, height, flip_t);
}
