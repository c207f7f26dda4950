MNI Tag Point File
Volumes = 2;
% Volume 1 produced by VTK
% Volume 2 produced by VTK

Points =
 -37.8125 12.34375 5.09375 -35.125 14.015625 3.6875 "anterior commissure"
 41.203125 -23.5 -11.671875 43.890625 -21.984375 -13.25 "posterior commissure"
 -0.171875 55.9375 30.015625 1.546875 57.25 28.4375 "left lateral ventricle tip"
 18.75 -60.140625 2.0625 20.328125 -58.75 0.828125 "right eye centre"
 -72.453125 -4.3125 -28.90625 -70.0625 -2.703125 -30.375 "4th ventricle";
