"""Wall modelling of one room (thesis 5.2): from the furniture slice of a levelled cloud to a topologically
correct 2D model of the inner wall faces, extruded from floor to ceiling.

`tasks.walls.model.model_walls(slice_points, floor_z_m, ceiling_z_m, cfg) -> WallModel` is pure: it reads
and writes nothing; `tasks.walls.stage.run` is the stage around it. Steps (thesis section in brackets):

0. round things (`round`): a plant's pot, a bin or a round column, an arc of 90° or more of a circle of
   0.15-0.6 m radius that explains most of the points near it and that three straight lines (over faces as
   long as its radius) explain no better, the walls it stands by left out, and with hardly a point just
   outside its arc (it was seen through the free space before it; a wall's noisy band a circle threads has
   as many there as on the circle), loses its points first (its facets would make stubs and false corners);
1. projection image (5.2.1, eq 5.3; `image`): the number of occupied voxels above each grid cell, so that
   the image measures wall height rather than point density (overlapping frames count once). The grid is
   `grid_size_m` or, on a sparse cloud, half its point spacing (`model.grid_from_data`, recorded in the
   metrics with the spacing);
2. binarization (5.2.2, `image`): eq 5.5 keeps the cells whose column is at least α = H_noise / H_filter
   full, so clutter shorter than α of the slice disappears (eq 5.4, μ - 1.65σ, as the alternative). A
   cell's data must also span `min_column_height_m`: table tops and ceiling patches are flat. Walls seen
   too sparsely for the grid (a stretch the camera passed quickly) are binarized the same way on a grid
   `sparse_grid_ratio` times coarser; when no α closes the room, those continuing the line of a wall found
   are added as bands where the fine image holds no wall cell nearby (`image.sparse_cells`) and the steps
   are made again (kept when that closes the room);
3. 3×3 closing and Zhang-Suen skeleton (5.2.3, `image`);
4. probabilistic Hough (5.2.4.1, `image`), β1 votes, β2 minimum length and β3 maximum gap given in metres;
5. 3-level clustering and regression averaging (5.2.4.2, `tasks.lines.merge_segments`), then the
   top-reach test on the merged lines (`evidence`): walls go on up to the ceiling, furniture and plants
   stop below it, so a line is kept when at least `min_top_share` of it lies on cells with data near the
   slice top. It is judged per line, not per cell, because a face seen from close range holds data only up
   to the camera's vertical view over most of its length. Two kinds of line below the top stay: the other
   face of a thin free-standing wall whose first face reaches the top (`thin_wall_faces`), and a long line
   with no top-reaching data parallel and close beside it (`unshadowed_lines`: furniture is seen in front
   of a wall seen above it, while a corridor captured from a metre away never reaches the top; a line's
   own unbroken band of data, `evidence.own_band`, shadows nothing: an end wall smeared by frames levelled
   a few degrees apart is one sloping wall, its top behind its foot);
6. regularization (5.2.5.1, eq 5.9, `tasks.lines.regularize`), refused for a line it would move by more
   than three times its data's noise (the larger of `topology.line_noise`, its Hough segments' spread, and
   `band_noise`, its wall cells' spread across it: a wall a few degrees off its neighbours keeps its angle,
   a short piece of a wide, noisy band does not); each wall's offset is refined to the median
   of the slice points near it (the skeleton is only good to a pixel), and its ends are moved out along it
   as far as its data goes (`extend_to_data`: the skeleton stops short of a band's end). A line whose
   band holds two faces `thin_wall_min_m` or more apart is a thin partition one binarization took as one
   wall: it becomes those two faces (`evidence.two_faces`, `split_faces`). A line wholly
   behind another, longer line of the room (more than `thin_wall_max_m` on its side away from the room),
   at least `through_gap_share` of it straight behind that line's data, was seen through a door in it: a
   wall of the next room, dropped before connecting (`evidence.seen_through_gaps`; an alcove's back wall
   lies behind its mouth, not behind the wall's data; a partition stub, its end open and the room going on
   behind it, hides nothing: what lies behind it was seen round its end; nor does an alcove's side, which
   faces the alcove, not the room's centre beyond its end: `backs_in_doubt`). In a slice with nothing seen
   above it (no ceiling) furniture reaches the slice top like the walls: a line the merge ran on past a
   reflex corner of the room (a wall turning off to its far side there) across a gap in its data is cut at
   the corner (`evidence.split_past_corners`: a wardrobe's front in line with an alcove's side), and the
   faces are told by where they stand (`evidence.furniture_in_front`, `lone_directions`; a cabinet filling
   an alcove by the alcove's sides seen running on past its front, a face standing free by the room's walls
   running on past its line at both its ends), a front the capture saw through (an open shelf's books)
   moves onto the wall seen behind it (`evidence.seen_through_fronts`), and a front in a recess whose side,
   starting from the room's wall, was seen running on past it moves back to where that side's data end
   (`evidence.recess_backs`: a wardrobe in an alcove whose other side the capture missed). The two sides of
   a step of a few cm do not run on over each other along their data (`topology.stop_at_steps`);
7. topology (5.2.5.2, `tasks.connect.connect_detailed`; `topology`): extension and trimming (trimming only
   overshoot, not a wall's observed data; an end moves out no further than where a parallel line within
   `lines.offset_tol_m` begins, the other side of a step), perpendicular joins of free ends onto parallel
   walls, removal of extensions with less than `min_overlap` of data, one at a time and judged with the
   regularization rotation undone. A join across an unseen wall goes where the data holds it, else at the end of the wall
   nearer the room's interior (its reflex corner, seen from anywhere in the room). The room is the
   largest face the walls enclose when the walls on or inside it hold most of the wall length; walls
   outside it (seen through doors and windows), groups hung from the ceiling (lamps) and dangling walls
   shorter than `min_wall_length_m` go. When the walls do not close, collinear pieces are bridged across
   the wider `bridge_gaps_m`, kept when that closes the room. A room that stays open all the same (a
   corner unseen at every height, which fusion closes along the plan) still gets the collinear gaps its
   slice points back (`evidence.backed_bridges`: free ends facing each other, nothing standing between,
   and half the gap's 10 cm bins holding `bridge_seen_ratio` of the median bin along the room's observed
   walls; a door holds none), and when no candidate α closes the room, those bridges and the corners one
   wall's data pin (`topology.pinned_corners`) are added to every candidate, kept when that closes it.
   When nothing pins them either (a handheld scan's spans seen at no height, 0.5 m and more short of each
   corner), the unseen spans are closed along the walls' lines (`close_unseen_spans`, `pinned_corners` with
   `across_unseen`): a corner both walls point at (an end up to 10 cm past it too: a far Kinect's noise along
   an obliquely seen wall), each running on unseen for no more than twice its line is seen over (any distance
   when that is a metre, or when it starts from a seen corner of the room in a direction a long wall confirms
   or in one more than 10° from every long wall's: a trapezoid's slanted wall; or when, in a confirmed
   direction, at most 1 % of the slice points lie beyond its line, not counting those beyond a long wall
   across it too, off the room's corner: a sparse scan's far wall seen over a few dm), with no other wall in
   the corner's parallelogram (an L-room's seen notch) nor behind an added piece (a partition stub's face run
   across the room has the room's far walls behind it; a furniture front has the wall's points just behind
   it); a collinear gap whose pieces lie on each other's lines with no wall behind it (an alcove's back wall);
   a free end run along its line to a wall as far as its line is seen over; a door's jamb standing free across
   a wall's line stops none of these (`_jambs`), nor a furniture box's side at a wall's end with the box's
   front seen beyond it (`_box_sides`: the wall runs on behind the box), and a partition's end cap is no wall
   the partition stands on; a box's seen side and short front against a wall seen up to the box, which close
   as a step in that wall, are left out where the room then closes (`_box_fronts`); kept when the room then
   closes and holds `UNSEEN_HELD_MIN_SHARE` of the slice points, leaving out those apart from all it holds (a
   wall seen through a door) (`corners_closed` in the metrics says which closed it).
   Walls are turned to have the room on their left;
8. extrusion (5.2.6, `model`) to a triangle mesh, and a preview picture.

Choosing α (`topology.choose_alpha`): the thesis has a person raise α until the clutter disappears. Here every
candidate α runs steps 2-7 (without the point-level offset refinement) and its model is summarised as its set
of walls. Walls are stable over a wide range of α (their columns are full), clutter and noise are not (they
fade out gradually), and too large an α breaks the walls apart. The chosen α is the smallest of the longest
run of consecutive candidates that give a closed wall graph and the same walls (every wall end within
`stable_tol_m` of a wall of the neighbour's model); without a closed model, the longest run of equal models. A
model holding under half the candidates' median wall length does not count: closed, it is a closet the walls
of a poorly seen room enclose; open, the few lines the highest α leave. Nor does a closed model holding under
half the slice points (a cabinet's front closing a closet with the wall behind it, the room's other walls
seen apart from it). The chosen α is run again with the
refinement; when the refined walls do not close where the pixel model did (a sparse stretch it bridged), they
are closed at the corners their data pin or across unseen spans first, and only then is the pixel model kept.
Occupancy alone cannot tell a tall cabinet from the wall above a window (both fill part of the slice): the
top-reach test does that, not α.
"""
