#version 330 core
// The close pass's draw (passes/gaps.py): one point of 4 x 4 pixels per tile of u_tile_box, at
// the tile, where gap_dilate.frag.glsl found that some pixel of it may be closed (u_tiles.b);
// elsewhere outside the clip volume (nothing drawn: those pixels keep the depth the pass
// copied). Tile t covers pixels 4 t .. 4 t + 3: the point's centre is at 4 t + 2, and a point
// of size 4 covers exactly the pixel centres within +-2 of it. A point whose centre lies
// outside the viewport is clipped whole, so the partial tiles at the far edges of an image
// whose sides are not multiples of 4 are centred at most 1.5 pixels inside the edge instead:
// the point still covers the tile's pixels there, and one or two of the tile before: the close
// shader gives them the rule's result like any pixel, which is their copy unless their own
// tile may close them (and then it is drawn anyway).

uniform sampler2D u_tiles;   // the dilated tiles: b = 1 where a pixel may be closed
uniform ivec4 u_tile_box;    // x, y, width, height, in tiles
uniform vec2 u_image_size;   // pixels

void main() {
    ivec2 tile = u_tile_box.xy + ivec2(gl_VertexID % u_tile_box.z, gl_VertexID / u_tile_box.z);
    gl_PointSize = 4.0;
    if (texelFetch(u_tiles, tile, 0).b <= 0.0) {
        gl_Position = vec4(2.0, 2.0, 2.0, 1.0);  // clipped
        return;
    }
    vec2 center = min(vec2(tile) * 4.0 + 2.0, u_image_size - 1.5);
    gl_Position = vec4(center / u_image_size * 2.0 - 1.0, 0.0, 1.0);
}
